"""What a fitted impedance says about its own trustworthiness, in numbers and in words.

``diagnostics_of`` reduces an ``Estimate`` to the few numbers the warnings need
(``FitDiagnostics``: effective averages, coherences, the inputs' coherence and its chance
probability); ``fit_impedance`` stores them in its result, so ``fit.warnings`` needs nothing
else. ``fit_warnings`` turns a concrete fit into one-line warnings: host-side (NumPy), one fit
at a time.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .._model.timing import CONTROL_PERIOD
from .estimate import Estimate
from .parametric import ELEMENTS
from .plausibility import plausibility_warnings

LACK_OF_FIT_ALPHA = 1e-3  # p-value below which the model is said not to fit
LOW_COHERENCE = 0.5  # a multiple coherence below this somewhere in the band
INPUT_COHERENCE_GUIDE = 0.4  # the paper's bound on the perturbation axes' ordinary coherence
FEW_AVERAGES = 4.0  # effective Welch averages below which the error model is rough
TIMING_SHIFT = 0.5  # standard errors: a delay that could be a mass lag moves M or B this far
STICK_SLIP_EXCESS = 0.15  # force_excess that shows joint stick-slip (docs/estimation.md section 3)
CHANNELS = ("fh_x", "fh_y", "x", "y")  # the multiple coherences' outputs, in FitDiagnostics' order


class FitDiagnostics(NamedTuple):
    """Numbers about the estimate a fit came from (a pytree; NaN where unknown).

    ``n_eff``: effective Welch averages (``ZError.n_eff``). ``coherence_min``,
    ``coherence_min_f`` [Hz], ``coherence_median``: ``(4,)``, the multiple coherence of each
    output ``CHANNELS`` (``fh_x, fh_y, x, y``) over the band: its smallest value, where, and its
    median. ``input_coherence``, ``input_coherence_f`` [Hz]: the perturbation axes' largest
    ordinary coherence and where; ``input_coherence_p``: the probability that independent
    inputs reach it by chance (``input_coherence_chance``). ``friction`` [N m]: the robot's
    largest Coulomb torque as the caller gave it (NaN: unknown); ``instant_samples``: 1 where
    the fit's model reads the force at an instant (``"instant"``), 0 where it does not
    (``"plain"``, ``"interval_mean"``), NaN where the fit asks the record (``"delay"``: instant
    when the delay's 95% interval reaches a quarter of ``period``); ``period`` [s]: the hold
    period the fit was given; ``force_excess`` ``(2,)``: ``Estimate.force_excess``, the hand
    force's broadband power the perturbation does not explain over its in-band power (NaN:
    unknown). Under ``jax.vmap`` every field gains the batch axis.
    """

    n_eff: jnp.ndarray
    coherence_min: jnp.ndarray
    coherence_min_f: jnp.ndarray
    coherence_median: jnp.ndarray
    input_coherence: jnp.ndarray
    input_coherence_f: jnp.ndarray
    input_coherence_p: jnp.ndarray
    friction: jnp.ndarray
    instant_samples: jnp.ndarray
    period: jnp.ndarray
    force_excess: jnp.ndarray


def unknown_diagnostics(n_eff=jnp.nan) -> FitDiagnostics:
    """Diagnostics of a fit to a bare ``Z`` array: nothing known but, at most, ``n_eff``."""
    nan, nan4 = jnp.full((), jnp.nan), jnp.full((4,), jnp.nan)
    n_eff = jnp.asarray(n_eff, dtype=jnp.float64)
    return FitDiagnostics(n_eff, nan4, nan4, nan4, nan, nan, nan, nan, nan, nan, jnp.full((2,), jnp.nan))


@jax.jit  # one program: op by op, each operation would compile on its own on a first fit
def diagnostics_of(est: Estimate) -> FitDiagnostics:
    """``FitDiagnostics`` of one ``Estimate`` (pure JAX; vmappable, differentiable where it
    matters to nobody: minima and medians)."""
    coh = jnp.concatenate([est.coh_multiple_fh, est.coh_multiple_x], axis=-1)  # (F, 4)
    coh = jnp.where(jnp.isfinite(coh), coh, jnp.inf)
    at = jnp.argmin(coh, axis=0)
    ci = jnp.where(jnp.isfinite(est.coh_inputs), est.coh_inputs, -jnp.inf)
    k = jnp.argmax(ci)
    if est.error is None:
        n_eff, chance = jnp.nan, jnp.full((), jnp.nan)
    else:
        n_eff = est.error.n_eff
        chance = _chance(ci[k], n_eff, est.error.bin_corr, ci.shape[0])
    return unknown_diagnostics(n_eff)._replace(
        coherence_min=jnp.min(coh, axis=0),
        coherence_min_f=est.f[at],
        coherence_median=jnp.nanmedian(jnp.where(jnp.isinf(coh), jnp.nan, coh), axis=0),
        input_coherence=ci[k],
        input_coherence_f=est.f[k],
        input_coherence_p=chance,
        force_excess=jnp.full((2,), jnp.nan) if est.force_excess is None else jnp.asarray(est.force_excess),
    )


def _chance(c, n_eff, bin_corr, n_bins: int):
    """P(max over the band of independent inputs' coherence > c): each about independent bin's
    sample coherence is ``Beta(1, n_eff - 1)`` (Carter 1973), ``P(> c) = (1 - c)^(n_eff - 1)``,
    over ``F / (1 + 2 sum bin_corr[1:]^2)`` about independent bins."""
    bins = n_bins / (1.0 + 2.0 * jnp.sum(jnp.asarray(bin_corr)[1:] ** 2))
    per_bin = jnp.minimum((1.0 - c) ** jnp.maximum(n_eff - 1.0, 0.0), 1.0 - 1e-16)
    return -jnp.expm1(bins * jnp.log1p(-per_bin))


def input_coherence_chance(est: Estimate) -> tuple[float, float]:
    """The largest ordinary coherence of the two inputs over the band, and the probability
    that independent inputs reach it by chance (NaN without ``est.error``). Host-side, one
    estimate. Short records reach the paper's 0.4 by chance: 30 s at Table 4's segments
    (``n_eff`` about 6) typically 0.6."""
    if np.ndim(np.asarray(est.coh_inputs)) != 1:
        raise ValueError("input_coherence_chance takes one estimate, not a batch")
    d = diagnostics_of(est)
    return float(d.input_coherence), float(d.input_coherence_p)


def fit_warnings(fit, est: Estimate | None = None, *, acquisition: str | None = None, friction: float | None = None):
    """What makes a fit's intervals untrustworthy, in words (an empty list when nothing does).

    ``fit``: one concrete ``ImpedanceFit``. Its own ``diagnostics`` are used, or those of
    ``est`` when given. ``acquisition`` (the fit's) and ``friction`` (the robot's largest
    Coulomb torque [N m]) override what the fit recorded (``fit_impedance(..., friction=)``):
    with instant force samples (``"instant"``, or a ``"delay"`` fit at the hold's lag) it warns
    of friction's bias when ``friction > 0``, or, with the friction unknown, when the record
    shows stick-slip (``force_excess`` above ``STICK_SLIP_EXCESS``; docs/estimation.md section
    3); a friction told 0 is believed.

    Each warning is one line saying what was seen and what it means: M or K negative on the
    diagonal, which no human arm gives, with its likely cause (``plausibility_warnings``: the
    force's sign, the sample rate, units), a significant lack of fit, standard errors that
    could not be computed, few effective averages, a low multiple coherence, correlated inputs
    beyond chance, a fitted delay whose reading as the hold's lag on the mass would move M or B
    by more than ``TIMING_SHIFT`` standard errors, and instant samples through friction (told,
    or seen as stick-slip).
    """
    if np.ndim(np.asarray(fit.lack_of_fit_p)) != 2:
        raise ValueError(
            "fit_warnings takes one fit (not a batch): index it first, e.g. jax.tree.map(lambda a: a[i], fits)"
        )
    own = FitDiagnostics(*(np.asarray(v, dtype=float) for v in fit.diagnostics))
    diag = own if est is None else FitDiagnostics(*(np.asarray(v, dtype=float) for v in diagnostics_of(est)))
    friction = float(own.friction) if friction is None else float(friction)
    instant = _instant_samples(fit, own, acquisition)
    out = [*implausible(fit), *_lack_of_fit_warning(fit), *_se_warning(fit), *_estimate_warnings(diag)]
    out += _timing_warning(fit)
    return out + (_friction_warning(friction, diag.force_excess) if instant else [])


def implausible(fit) -> list[str]:
    """A warning where ``fit`` (one concrete ``ImpedanceFit``) has M or K negative on the
    diagonal (the classical rule of ``_model.plausibility``), with its likely cause."""
    names = ("mass", "damping", "stiffness")
    values = {n: np.asarray(getattr(fit, n)) for n in names}
    return plausibility_warnings(values, {n: np.asarray(getattr(fit, f"{n}_se")) for n in names}, classical=True)


def _friction_warning(friction: float, excess) -> list[str]:
    """Instant samples through friction: told (``friction > 0``), or, with the friction unknown
    (NaN), seen as stick-slip's broadband force in the record; a friction told 0 is believed."""
    consequence = (
        "the sampled-data model assumes the hand accelerates as the linear arm alone would within each hold "
        "period; friction changes that and biases M (low) and B without a trace in coherence or lack of fit, so "
        "the intervals may miss; interval-mean (integrating) acquisition has no such bias"
    )
    if friction > 0:
        return [f"instant force samples through a robot with joint friction: {consequence}"]
    seen = np.nanmax(excess) if np.any(np.isfinite(excess)) else np.nan
    if not (np.isnan(friction) and seen > STICK_SLIP_EXCESS):
        return []
    return [
        f"stick-slip in the record: above the band the hand force carries power the perturbation does not explain, "
        f"{100 * seen:.0f}% of its in-band power (over {100 * STICK_SLIP_EXCESS:.0f}%: the jerks of joint friction, "
        f"or a noisy force sensor); with instant force samples {consequence}; pass friction=0 if the robot has none"
    ]


def _instant_samples(fit, own: FitDiagnostics, acquisition: str | None) -> bool:
    """Does the fit read the force at an instant? Told, or for a delay fit, asked of the record:
    a fitted delay whose 95% interval reaches a quarter of the hold period is consistent with
    the hold's lag of instant samples (about half a period); interval means give about 0."""
    if acquisition is None and not np.isnan(own.instant_samples):
        return bool(own.instant_samples == 1)
    if acquisition not in (None, "delay"):
        return acquisition == "instant"
    if not np.isfinite(np.asarray(fit.delay_dof)):
        return False
    high = fit.interval("delay")[1]
    period = own.period if np.isfinite(own.period) else CONTROL_PERIOD
    return bool(high > 0.25 * period)


def _lack_of_fit_warning(fit) -> list[str]:
    p_all = float(np.asarray(fit.lack_of_fit_p_overall))
    p_el, ratio_el = np.asarray(fit.lack_of_fit_p), np.asarray(fit.lack_of_fit)
    if not (p_all < LACK_OF_FIT_ALPHA or np.any(p_el < LACK_OF_FIT_ALPHA)):
        return []
    worst = max(ELEMENTS, key=lambda e: ratio_el[e])
    return [
        f"lack of fit: the residuals are {float(np.asarray(fit.lack_of_fit_overall)):.3g} times their predicted "
        f"variance (p = {p_all:.2g}; worst Z{'xy'[worst[0]]}{'xy'[worst[1]]}: {ratio_el[worst]:.3g}, "
        f"p = {p_el[worst]:.2g}): M s^2 + B s + K (with this acquisition) does not describe Z, so M, B, K and "
        "their intervals describe a wrong model (friction, a non-linearity or a wrong acquisition setting)"
    ]


def _se_warning(fit) -> list[str]:
    if all(np.all(np.isfinite(np.asarray(getattr(fit, n)))) for n in ("mass_se", "damping_se", "stiffness_se")):
        return []
    return [
        "standard errors unavailable (NaN): too few Welch segments to estimate the residual spectrum "
        "(need more than about 4: a longer record or a shorter nperseg)"
    ]


def _estimate_warnings(d: FitDiagnostics) -> list[str]:
    out = []
    if d.n_eff < FEW_AVERAGES:
        out.append(
            f"few averages: {float(d.n_eff):.1f} effective Welch averages (segments over the overlap's "
            "correlation): the error model is first order and rough here (intervals measured too wide, the "
            "lack-of-fit test weak, chance coherences high); use a longer record or a shorter nperseg"
        )
    low = [
        f"{name} {d.coherence_min[k]:.2f} at {d.coherence_min_f[k]:.3g} Hz (median {d.coherence_median[k]:.2f})"
        for k, name in enumerate(CHANNELS)
        if d.coherence_min[k] < LOW_COHERENCE
    ]
    if low:
        out.append(
            f"low coherence: multiple coherence down to {'; '.join(low)}: much of the output is not explained "
            "linearly by the perturbation there (friction, other non-linearity or noise); estimates are noisy "
            "and may be biased"
        )
    if d.input_coherence > INPUT_COHERENCE_GUIDE and not d.input_coherence_p >= 0.01:
        why = (
            ""
            if np.isnan(d.input_coherence_p)
            else (
                f", more than independent inputs reach by chance at {float(d.n_eff):.1f} averages "
                f"(p = {float(d.input_coherence_p):.2g})"
            )
        )
        out.append(
            f"input coherence {float(d.input_coherence):.2f} at {float(d.input_coherence_f):.3g} Hz exceeds the "
            f"paper's guide {INPUT_COHERENCE_GUIDE}{why}: the two perturbation axes are correlated, so Z's columns "
            "are poorly separated (wider intervals)"
        )
    return out


def timing_shift(fit) -> float:
    """How far, in standard errors, M or B would move if a fitted delay ``tau`` were the hold's
    lag on the mass instead of a force-channel delay: ``max |tau B| / se(M), |tau K| / se(B)``
    over the elements (0 for a fit without a delay). To first order the two timings give the
    same recorded ``Z`` with ``M -> M + tau B``, ``B -> B + tau K``: the record cannot tell them
    apart (docs/estimation.md section 2)."""
    tau = float(np.asarray(fit.delay))
    if not np.isfinite(np.asarray(fit.delay_dof)) or tau == 0.0:
        return 0.0
    with np.errstate(divide="ignore", invalid="ignore"):
        on_m = np.abs(tau * np.asarray(fit.damping)) / np.asarray(fit.mass_se)
        on_b = np.abs(tau * np.asarray(fit.stiffness)) / np.asarray(fit.damping_se)
    return float(np.nanmax(np.concatenate([on_m.ravel(), on_b.ravel()])))


def _timing_warning(fit) -> list[str]:
    shift = timing_shift(fit)
    if not shift > TIMING_SHIFT:
        return []
    tau_ms = 1e3 * float(np.asarray(fit.delay))
    return [
        f"timing: the fitted force-channel delay {tau_ms:.3g} ms could equally be the hold's lag on the mass "
        f"(force sampled at the control instants: about half a period), which moves M or B by up to "
        f"{shift:.2g} standard errors (M by tau B, B by tau K); the record cannot tell the two apart. If the "
        "samples are instant, fit acquisition='instant' with the hold period; if the force channel is known to "
        "lag by this delay, the intervals hold as printed"
    ]
