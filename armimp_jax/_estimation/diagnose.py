"""Warnings in words for a fitted impedance: when the classical route cannot be trusted.

``fit_warnings`` reads a concrete ``ImpedanceFit`` (its lack-of-fit test and standard
errors) and, optionally, its ``Estimate`` (coherences); ``input_coherence_chance`` says
whether the perturbation axes' coherence is more than short records give by chance.
Host-side (NumPy) functions of one fit: not for ``jit`` or ``vmap``.
"""

from __future__ import annotations

import numpy as np

from .fit import ELEMENTS, ImpedanceFit
from .welch import Estimate

LACK_OF_FIT_ALPHA = 1e-3  # p-value below which the model is said not to fit
LOW_COHERENCE = 0.5  # a multiple coherence below this somewhere in the band
INPUT_COHERENCE_GUIDE = 0.4  # the paper's bound on the perturbation axes' ordinary coherence
FEW_AVERAGES = 4.0  # effective Welch averages below which the error model is rough


def fit_warnings(
    fit: ImpedanceFit, est: Estimate | None = None, *, acquisition: str | None = None, friction: float | None = None
) -> list[str]:
    """What makes a fit's intervals untrustworthy, in words (an empty list when nothing does).

    ``acquisition`` (the fit's) and ``friction`` (the robot's largest Coulomb torque [N m],
    ``None`` when unknown) add what no statistic of the record shows: force samples taken at
    an instant (``"instant"``, ``"delay"``) through a robot with joint friction, whose
    within-period acceleration the sampled-data model does not describe (docs/estimation.md
    section 3). It fires when ``friction`` is ``> 0`` or unknown.

    Checks (single concrete fit): a significant lack of fit (``lack_of_fit_p_overall`` or an
    element's p-value below ``LACK_OF_FIT_ALPHA``), standard errors that could not be
    computed, and, with the ``Estimate``, fewer than ``FEW_AVERAGES`` effective averages, a
    multiple coherence below ``LOW_COHERENCE`` somewhere in the band and an input coherence
    above ``INPUT_COHERENCE_GUIDE`` (the paper's 0.4) that independent inputs would reach by
    chance with probability below 1% (``input_coherence_chance``; without ``est.error``, any
    value above the guide). Each warning is one line saying what was seen and what it means.
    """
    out = []
    p_all = float(np.asarray(fit.lack_of_fit_p_overall))
    p_el = np.asarray(fit.lack_of_fit_p)
    if np.ndim(p_el) != 2:
        raise ValueError(
            "fit_warnings takes one fit (not a batch): index it first, e.g. jax.tree.map(lambda a: a[i], fits)"
        )
    ratio_el = np.asarray(fit.lack_of_fit)
    bad = [(i, j) for i, j in ELEMENTS if p_el[i, j] < LACK_OF_FIT_ALPHA]
    if p_all < LACK_OF_FIT_ALPHA or bad:
        worst = max(ELEMENTS, key=lambda e: ratio_el[e])
        out.append(
            f"lack of fit: the residuals are {float(np.asarray(fit.lack_of_fit_overall)):.3g} times their predicted "
            f"variance (p = {p_all:.2g}; worst Z{'xy'[worst[0]]}{'xy'[worst[1]]}: {ratio_el[worst]:.3g}, "
            f"p = {p_el[worst]:.2g}): M s^2 + B s + K (with this acquisition) does not describe Z, so M, B, K and "
            "their intervals describe a wrong model (friction, a non-linearity or a wrong acquisition setting)"
        )
    for name in ("mass_se", "damping_se", "stiffness_se"):
        if not np.all(np.isfinite(np.asarray(getattr(fit, name)))):
            out.append(
                "standard errors unavailable (NaN): too few Welch segments to estimate the residual spectrum "
                "(need more than about 4: a longer record or a shorter nperseg)"
            )
            break
    if est is not None and est.error is not None and float(np.asarray(est.error.n_eff)) < FEW_AVERAGES:
        out.append(
            f"few averages: {float(np.asarray(est.error.n_eff)):.1f} effective Welch averages (segments over the "
            "overlap's correlation): the error model is first order and rough here (intervals measured too wide, "
            "the lack-of-fit test weak); use a longer record or a shorter nperseg"
        )
    if est is not None:
        low = []
        for field, names in (("fh", ("fh_x", "fh_y")), ("x", ("x", "y"))):
            c = np.asarray(getattr(est, f"coh_multiple_{field}"))
            for k, name in enumerate(names):
                if np.nanmin(c[:, k]) < LOW_COHERENCE:
                    at = float(np.asarray(est.f)[int(np.nanargmin(c[:, k]))])
                    low.append(f"{name} {np.nanmin(c[:, k]):.2f} at {at:.3g} Hz (median {np.nanmedian(c[:, k]):.2f})")
        if low:
            out.append(
                f"low coherence: multiple coherence down to {'; '.join(low)}: much of the output is not explained "
                "linearly by the perturbation there (friction, other non-linearity or noise); estimates are noisy "
                "and may be biased"
            )
        ci_max, chance = input_coherence_chance(est)
        if ci_max > INPUT_COHERENCE_GUIDE and not chance >= 0.01:
            at = float(np.asarray(est.f)[int(np.nanargmax(np.asarray(est.coh_inputs)))])
            why = "" if np.isnan(chance) else f", more than independent inputs reach by chance (p = {chance:.2g})"
            out.append(
                f"input coherence {ci_max:.2f} at {at:.3g} Hz exceeds the paper's guide {INPUT_COHERENCE_GUIDE}{why}: "
                "the two perturbation axes are correlated, so Z's columns are poorly separated (wider intervals)"
            )
    if acquisition in ("instant", "delay") and (friction is None or friction > 0):
        robot = (
            "a robot with joint friction" if friction is not None else "a robot with joint friction (if yours has any)"
        )
        out.append(
            f"instant force samples through {robot}: the sampled-data model assumes the hand accelerates as the "
            "linear arm alone would within each hold period; friction changes that and biases M (low) and B without "
            "a trace in coherence or lack of fit, so the intervals may miss; interval-mean (integrating) acquisition "
            "has no such bias"
        )
    return out


def input_coherence_chance(est: Estimate) -> tuple[float, float]:
    """The largest ordinary coherence of the two inputs over the band, and the probability
    that independent inputs reach it by chance (NaN without ``est.error``).

    With ``n`` independent averages the sample coherence of independent signals is
    ``Beta(1, n - 1)`` (Carter 1973), ``P(> c) = (1 - c)^(n - 1)``; here ``n = error.n_eff``,
    and the maximum runs over ``F / (1 + 2 sum bin_corr[1:]^2)`` about independent bins.
    Short records reach the paper's 0.4 by chance: 30 s (``n_eff`` about 6) typically 0.6.
    """
    ci = np.asarray(est.coh_inputs)
    if np.ndim(ci) != 1:
        raise ValueError("input_coherence_chance takes one estimate, not a batch")
    c = float(np.nanmax(ci))
    if est.error is None:
        return c, float("nan")
    n_eff = float(np.asarray(est.error.n_eff))
    rho = np.asarray(est.error.bin_corr)
    bins = len(ci) / (1.0 + 2.0 * float(np.sum(rho[1:] ** 2)))
    per_bin = (1.0 - c) ** max(n_eff - 1.0, 0.0)
    return c, float(-np.expm1(bins * np.log1p(-min(per_bin, 1.0 - 1e-16))))
