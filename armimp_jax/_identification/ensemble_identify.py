"""The model route over an ensemble of reaches: ``identify(model, ensemble=...)``.

Each repetition records ``y_r = mu(theta, f_r) + v_r`` (``path_bound.py``). Subtracting the
ensemble's mean at each sample makes the mean path a free nuisance (a fixed effect per sample);
what is left is fitted by generalised least squares with the noise whitened by the time-varying
Kalman filter of the loop linearised along the path (``path.py``):

    min_theta sum_r || W(theta) [ (y_r - y_bar) - (mu(theta, f_r) - mu_bar(theta)) ] ||^2,

by a chord iteration from the classical route's answer (``estimate_ensemble``): the Jacobian and
the filter held at the start (one binding serves every repetition and every step), so its fixed
point solves ``J_0^T W_0 r(p) = 0``; at the answer both are computed anew for the covariance
``(sum_r J_r^T J_r)^-1`` (the bound at the estimate), and the step they would still take is
reported (``refreshed_step``, in SEs) and warned of above ``REFRESH_WARN``. The whitened
residuals' variance is checked against the model's noise (1 when the trial's
noise levels are the lab's): above it the intervals are widened by it and a warning says why.

Friction: refused. With ``mu`` the noise-free simulation through the friction, the noise whitened
by the loop without it and the Coulomb torque a nuisance, the route walked off the classical
answer under IMBIC through LuGre 0.5 N m (M 12-17% low on 5 of 5 ensembles of 40 reaches): the
noise-free loop is not the mean of the noisy one through friction, which the still ``identify``
answers by simulating the noise (indirect inference); over an ensemble that is still to build.
"""

from __future__ import annotations

import dataclasses
import functools
import importlib.metadata
import time

import jax
import jax.numpy as jnp
import numpy as np
from scipy.stats import norm

from .._checks import require_x64
from .._estimation.ensemble import Ensemble
from .._estimation.ensemble_fit import estimate_ensemble
from .._simulate import Trial
from . import path as ph
from . import path_bound as pb
from .bound import has_friction
from .indirect import IDENTIFY_NUMERICS

MIN_REPETITIONS = 8  # below this the ensemble's mean path (a nuisance per sample) takes too much of the data
MEASURED_REPETITIONS = 40  # the Monte Carlo's ensembles (docs/movement.md); fewer are warned of
TOLERANCE = 0.01  # a step below this fraction of every SE ends the search
REFRESH_WARN = 0.1  # [SE] a step the refreshed Jacobian would still take beyond this is warned of
# The pairs (controller, friction or "none") whose intervals the Monte Carlo measured over ensembles.
MEASURED = {("imbic", "none"), ("pd", "none")}


@dataclasses.dataclass(frozen=True)
class EnsembleIdentification:
    """``identify``'s answer over an ensemble (host values).

    ``labels`` (``"arm.stiffness@t=0.6[0,0]"``, row by row per knot), ``estimate``, ``se``,
    ``start`` ``(n,)``; ``covariance`` ``(n, n)``; ``converged``, ``steps``, ``message``;
    ``refreshed_step``: the largest step, in SEs, the Jacobian and filter at the answer would take;
    ``noise_ratio``: the whitened residuals' variance over the model's (1 when the trial's noise is
    the lab's; the intervals are widened by it above 1); ``warnings`` in a lab's terms;
    ``repetitions``, ``seconds`` (wall time), ``settings`` (everything the call was given, and the version)."""

    labels: list
    estimate: np.ndarray
    se: np.ndarray
    start: np.ndarray
    covariance: np.ndarray
    converged: bool
    steps: int
    message: str
    noise_ratio: float
    refreshed_step: float
    warnings: tuple
    repetitions: int
    seconds: float
    settings: dict

    def interval(self, label: str, level: float = 0.95) -> tuple[float, float]:
        """The ``level`` interval of one entry (normal: the information of every repetition)."""
        if label not in self.labels:
            raise ValueError(f"EnsembleIdentification: unknown entry {label!r}; entries: {self.labels}")
        i, z = self.labels.index(label), float(norm.ppf(0.5 + level / 2))
        return float(self.estimate[i] - z * self.se[i]), float(self.estimate[i] + z * self.se[i])

    def table(self, level: float = 0.95):
        """A pandas table: each entry's estimate, SE and ``level`` interval."""
        import pandas as pd

        z = float(norm.ppf(0.5 + level / 2))
        return pd.DataFrame(
            {
                "entry": self.labels,
                "estimate": self.estimate,
                "se": self.se,
                "low": self.estimate - z * self.se,
                "high": self.estimate + z * self.se,
            }
        )

    def summary(self, level: float = 0.95) -> str:
        state = "converged" if self.converged else f"NOT converged: {self.message}"
        lines = [f"identify over {self.repetitions} reaches: {state} in {self.steps} steps, {self.seconds:.0f} s"]
        z = float(norm.ppf(0.5 + level / 2))
        for label, v, s in zip(self.labels, self.estimate, self.se, strict=True):
            if label.endswith(("[0,0]", "[1,1]")) or label.startswith("friction"):
                lines.append(f"  {label:32s} {v:10.4g}  [{v - z * s:.4g}, {v + z * s:.4g}]")
        lines += [f"WARNING: {w}" for w in self.warnings]
        return "\n".join(lines)


@functools.partial(jax.jit, static_argnames=("layout", "numerics"))
def _binding(layout, trial, p, f, numerics):
    """``(filter, mu (R, N, 4), J (R, N, 4, n))`` at ``p``: one program for every repetition."""
    filt = ph.path_filter(ph.path_loop(ph.with_values(layout, trial, p), f.shape[1], numerics))
    mu, jac = ph.response_jacobians(layout, trial, p, f, numerics)
    return filt, mu, jac


@functools.partial(jax.jit, static_argnames=("layout", "numerics"))
def _responses(layout, trial, p, f, numerics):
    """``(mu (R, N, 4), diverged (R,))`` at ``p``."""
    return jax.lax.map(lambda fr: ph.deterministic(ph.with_values(layout, trial, p), fr, numerics, diverged=True), f)


@jax.jit
def _whiten_centred(filt, z):
    """Each repetition's whitened signal less the ensemble's mean (``W`` is linear)."""
    w = jax.vmap(lambda zr: ph.whiten(filt, zr))(z)
    return w - jnp.mean(w, axis=0, keepdims=True)


def _recorded(ensemble: Ensemble, trial: Trial) -> np.ndarray:
    return np.concatenate([ensemble.x - np.asarray(trial.x0), ensemble.fh], axis=2)


def _check(model, ensemble, free, where: str) -> tuple[Ensemble, ph.KnotLayout]:
    if not isinstance(model, Trial):
        raise ValueError(f"{where}: over an ensemble, model must be a Trial (the reach, its profiles' knots free)")
    if not isinstance(ensemble, Ensemble):
        raise ValueError(
            f"{where}: ensemble must be an Ensemble (simulate_ensemble, load_ensemble), got {type(ensemble).__name__}"
        )
    if ensemble.f_delta is None:
        raise ValueError(f"{where}: the ensemble holds no perturbations: the model route needs each reach's F_Delta")
    if abs(ensemble.period - float(model.period)) > 1e-12:
        raise ValueError(
            f"{where}: the ensemble is sampled every {ensemble.period:g} s and the model's loop every "
            f"{float(model.period):g} s"
        )
    sound = ensemble.sound()
    if sound.repetitions < MIN_REPETITIONS:
        raise ValueError(
            f"{where}: {sound.repetitions} sound repetitions; the model route needs at least {MIN_REPETITIONS} "
            "(the ensemble's "
            "mean path takes one repetition's worth of the data)"
        )
    layout = ph.knot_layout(model, free, where=where)
    ph.check_reach_model(model, layout, sound.samples, where)
    if np.allclose(sound.f_delta, sound.f_delta[:1]):
        raise ValueError(
            f"{where}: every reach has the same perturbation: less the ensemble's mean nothing is left to tell "
            "the arm; "
            "draw each reach's perturbation anew"
        )
    if not model.noisy:
        raise ValueError(f"{where}: the model has no noise (Sensors, VoluntaryForce): the intervals rest on it")
    return sound, layout


def _classical_start(layout: ph.KnotLayout, model: Trial, ensemble: Ensemble) -> np.ndarray:
    """The classical route's answer on ``layout``'s knots (the model's values where it cannot run)."""
    p = np.asarray(ph.pack(layout, model)).copy()
    knots = sorted({t for ks in layout.knots for t in ks})
    try:
        fit = estimate_ensemble(ensemble, knots=knots or None)
    except ValueError:  # too few reaches, or knots the window cannot hold: the model's own values
        return p
    at = 0
    for name, ks in zip(layout.names, layout.knots):
        attr = name.split(".")[1]
        values = fit.mass[None] if attr == "mass" else getattr(fit, attr)
        block = (
            values if attr == "mass" else np.stack([values[knots.index(t)] for t in ks]) if ks else values.mean(0)[None]
        )
        n = 4 * block.shape[0]
        p[at : at + n] = block.reshape(-1)
        at += n
    return p


def _controller_name(model: Trial) -> str:
    return type(model.controller).__name__.lower()


def _warnings(model, sound, noise_ratio, refreshed) -> list[str]:
    out = []
    kind = (_controller_name(model), type(model.friction).__name__.lower() if has_friction(model) else "none")
    if kind not in MEASURED:
        out.append(
            f"the model route over an ensemble has not been measured by Monte Carlo for {kind[0]} through "
            f"{kind[1]} friction: treat its intervals as provisional (docs/movement.md)"
        )
    if sound.repetitions < MEASURED_REPETITIONS / 2:
        out.append(
            f"{sound.repetitions} reaches: the intervals were measured with {MEASURED_REPETITIONS}; "
            "record more reaches "
            "(reaches_for says how many a precision needs)"
        )
    if refreshed > REFRESH_WARN:
        out.append(
            f"the answer is {refreshed:.2f} SE from where the Jacobian at it points (more than {REFRESH_WARN:g}): the "
            "fit is not linear across its intervals; record more reaches, or start nearer (start=)"
        )
    if noise_ratio > 1.5 or noise_ratio < 0.5:
        out.append(
            f"the reaches' noise is {noise_ratio:.2f} times the model's (its person's force and sensor noise): the "
            "intervals are widened by it where above 1; set the trial's Sensors and VoluntaryForce to the lab's"
        )
    return out


def identify_ensemble(
    model: Trial, ensemble: Ensemble, *, free=ph.ARM, numerics=None, max_steps: int = 8, start=None
) -> EnsembleIdentification:
    """The arm's ``M``, and ``B`` and ``K`` at every knot of the model's profiles, from an ensemble
    of reaches through the model (module docstring).

    Args:
        model: the reach (``make_trial`` with a moving arm): every fixed setting, the noise levels
            the intervals rest on, the profiles' knots (each knot's matrix is free).
        ensemble: the reaches (``simulate_ensemble``, ``load_ensemble``, ``Ensemble``), with each
            one's perturbation; diverged repetitions are left out.
        free: arm matrices (each knot's, where the model's matrix is a profile).
        numerics: the simulation's integrator (default ``IDENTIFY_NUMERICS``).
        max_steps: Gauss-Newton steps at most.
        start: ``(n,)`` start (default: the classical route's answer on the knots).
    """
    require_x64("identify")
    t0 = time.perf_counter()
    sound, layout = _check(model, ensemble, free, "identify")
    numerics = numerics or IDENTIFY_NUMERICS
    f = jnp.asarray(sound.f_delta)
    if has_friction(model):
        raise ValueError(
            "identify: over an ensemble, the model route does not yet go through Coulomb friction (measured: under "
            "IMBIC through LuGre 0.5 N m it walked off the classical answer, M 12-17% low, on 5 of 5 ensembles of "
            "40 reaches); use estimate_ensemble (the classical route), or identify each still posture"
        )
    p_start = _classical_start(layout, model, sound) if start is None else np.asarray(start, dtype=np.float64)
    y = jnp.asarray(_recorded(sound, model))
    p, steps, converged, message = _search(layout, model, p_start, f, y, numerics, max_steps)
    cov, noise_ratio, refreshed = np.full((p.size, p.size), np.nan), float("nan"), float("nan")
    if not message:
        cov, noise_ratio, refreshed = _at_answer(layout, model, p, f, y, numerics, sound.repetitions)
    warnings = tuple(_warnings(model, sound, noise_ratio, refreshed)) if not message else ()
    free = (free,) if isinstance(free, str) else tuple(free)
    settings = dict(
        free=list(free), numerics=repr(numerics), max_steps=max_steps, version=importlib.metadata.version("armimp_jax")
    )
    return EnsembleIdentification(
        labels=layout.labels(),
        estimate=p,
        se=np.sqrt(np.maximum(np.diag(cov), 0.0)),
        start=p_start,
        covariance=cov,
        converged=converged,
        steps=steps,
        message=message,
        noise_ratio=noise_ratio,
        refreshed_step=refreshed,
        warnings=warnings,
        repetitions=sound.repetitions,
        seconds=time.perf_counter() - t0,
        settings=settings,
    )


def _search(layout, model, p, f, y, numerics, max_steps):
    """The chord iteration (module docstring): ``(p, steps, converged, message)``; a step that takes a
    simulated reach to divergence ends it at the last sound ``p``."""
    filt, mu, jac = _binding(layout, model, jnp.asarray(p), f, numerics)
    if np.any(np.asarray(_responses(layout, model, jnp.asarray(p), f, numerics)[1])):
        return p, 0, False, "the simulated reaches diverge at the start: check the model, or give start="
    wj = _whiten_centred(filt, jac)
    h = np.asarray(jnp.einsum("rkip,rkiq->pq", wj, wj))
    h_inv = pb.inverse(h, layout.labels(), "identify")
    se = np.sqrt(np.diag(h_inv))
    for steps in range(1, max_steps + 1):
        delta = h_inv @ np.asarray(jnp.einsum("rkip,rki->p", wj, _whiten_centred(filt, y - mu)))
        mu_new, diverged = _responses(layout, model, jnp.asarray(p + delta), f, numerics)
        if np.any(np.asarray(diverged)):
            return (
                p,
                steps,
                False,
                "a step took the simulated reaches to divergence: start nearer (start=) or check the model",
            )
        p, mu = p + delta, mu_new
        if np.max(np.abs(delta) / se) < TOLERANCE:
            return p, steps, True, ""
    return p, max_steps, False, f"no convergence in {max_steps} steps"


def _at_answer(layout, model, p, f, y, numerics, repetitions):
    """The covariance at ``p`` (widened by the noise ratio above 1), the noise ratio, and the step,
    in SEs, the Jacobian and filter at ``p`` would still take."""
    filt, mu, jac = _binding(layout, model, jnp.asarray(p), f, numerics)
    wj = _whiten_centred(filt, jac)
    resid = _whiten_centred(filt, y - mu)  # the filter at the answer whitens the data anew
    h_inv = pb.inverse(np.asarray(jnp.einsum("rkip,rkiq->pq", wj, wj)), layout.labels(), "identify")
    step = h_inv @ np.asarray(jnp.einsum("rkip,rki->p", wj, resid))
    noise_ratio = float(jnp.sum(resid**2)) / ((repetitions - 1) * resid.shape[1] * 4 - p.size)
    refreshed = float(np.max(np.abs(step) / np.sqrt(np.diag(h_inv))))
    return h_inv * max(noise_ratio, 1.0), noise_ratio, refreshed


def identify_over(model, ensemble, x, fh, calibration, *, free, numerics, max_steps) -> EnsembleIdentification:
    """``identify(model, ensemble, ...)``: refuses what the route does not take, then ``identify_ensemble``."""
    if x is not None or fh is not None or calibration is not None:
        raise ValueError("identify: with an ensemble, x, fh and calibration stay None (each reach holds its own)")
    return identify_ensemble(model, ensemble, free=free, numerics=numerics, max_steps=min(max_steps, 8))
