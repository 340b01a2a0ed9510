"""The controller as a design variable: its gains as a small vector, applied to trials, and
projected onto what a clinician allows (minimum stiffness and damping, the hand's drift under
the person's own force, stability with margin).

A design moves the log of the diagonal of the two gains the controller's kind names in
``DESIGN_GAINS`` (a stiffness [N/m] and a damping [N s/m]): IMBIC's desired ``k_rd`` and
``b_rd``, PD's ``kp`` and ``kv``, an admittance's virtual ``k_v`` and ``b_v``. The rest stays at
the trial's values (IMBIC's ``mhat`` and ``m_rd``: the time-delay estimation's stability is
set by ``mhat`` against the robot's inertia, which no gain here changes; an admittance's
virtual mass and servo). The designed gains are diagonal.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from .._identification import linear
from .._pytree import replace_unchecked
from .._simulate import Trial

STABILITY_MARGIN = 2.0  # the loop must stay stable with the designed gains times this (6 dB)
DRIFT_TOLERANCE = 1e-3  # of the drift limit, in the stiffening's bisection
MAX_STIFFENING = 6.0  # log of the largest factor the drift projection may raise stiffness by


def gain_names(trial: Trial) -> tuple[str, str]:
    """The constructor's names of the designed stiffness and damping gains (the kind's ``DESIGN_GAINS``)."""
    names = type(trial.controller).DESIGN_GAINS
    if names is None:
        raise ValueError(f"design: no gains to design for a {type(trial.controller).__name__} controller")
    return names


def initial_log_gains(trial: Trial) -> np.ndarray:
    """``(4,)``: log of the diagonal stiffness [N/m] and damping [N s/m] of the trial's controller."""
    k, b = gain_names(trial)
    stiff = np.diag(np.asarray(getattr(trial.controller, k)))
    damp = np.diag(np.asarray(getattr(trial.controller, b)))
    if np.any(stiff <= 0) or np.any(damp <= 0):
        raise ValueError(f"design: the controller's diagonal {k} and {b} must be > 0, got {stiff} and {damp}")
    return np.log(np.concatenate([stiff, damp]))


def with_gains(trial: Trial, log_gains) -> Trial:
    """``trial`` with its controller's stiffness and damping set to ``diag(exp(log_gains))``
    (traceable: the design differentiates through it)."""
    k, b = gain_names(trial)
    g = jnp.exp(jnp.asarray(log_gains))
    controller = trial.controller.with_gains(**{k: jnp.diag(g[:2]), b: jnp.diag(g[2:])})
    return replace_unchecked(trial, controller=controller)


def controller_record(trial: Trial) -> dict:
    """The controller as ``design.json`` writes it: its ``type`` (the kind) and the constructor's
    own argument names with 2x2 lists (the kind's ``record``)."""
    return trial.controller.record()


@jax.jit
def _drift_and_loops(trial, log_gains):
    loops = [linear.linearise(with_gains(trial, log_gains + s)) for s in (0.0, jnp.log(STABILITY_MARGIN))]
    drift = jnp.sqrt(jnp.trace(linear.stationary_cov(loops[0], ("voluntary",))[:2, :2]))
    return drift, [loop.a for loop in loops]


def _drift_and_radius(trial, log_gains):
    """The drift [m] at ``log_gains`` and the spectral radii ``(2,)`` there and with the gains times
    ``STABILITY_MARGIN`` (eigenvalues on the host: XLA has no general eigensolver on every device)."""
    drift, mats = _drift_and_loops(trial, jnp.asarray(log_gains))
    return float(drift), np.array([np.max(np.abs(np.linalg.eigvals(np.asarray(a)))) for a in mats])


def drift_and_stability(trials, log_gains) -> tuple[float, bool]:
    """The largest drift [m] over ``trials`` at ``log_gains`` and whether every loop is stable
    there and with the gains times ``STABILITY_MARGIN``."""
    worst, stable = 0.0, True
    for t in trials:
        d, r = _drift_and_radius(t, log_gains)
        stable &= bool(np.all(r < 1.0))
        worst = max(worst, d if np.isfinite(d) else np.inf)
    return worst, stable


def project(trials, log_gains, limits):
    """The nearest allowed gains: each at least its minimum, then the stiffness raised (both axes
    by one factor, bisected in log) until the drift is within its limit. Returns ``(log_gains,
    drift, stable)``; ``stable`` False when no allowed stiffening keeps the loop stable."""
    g = np.array(log_gains, dtype=float)
    floor = np.log(np.maximum([limits.min_stiffness] * 2 + [limits.min_damping] * 2, 1e-300))
    g = np.maximum(g, floor)
    d, stable = drift_and_stability(trials, g)
    if limits.drift is None or d <= limits.drift:
        return g, d, stable
    lift = np.array([1.0, 1.0, 0.0, 0.0])
    low, high = 0.0, MAX_STIFFENING
    d_high, stable_high = drift_and_stability(trials, g + high * lift)
    if d_high > limits.drift:
        return g + high * lift, d_high, False
    while high - low > DRIFT_TOLERANCE:
        mid = 0.5 * (low + high)
        d_mid, _ = drift_and_stability(trials, g + mid * lift)
        low, high = (mid, high) if d_mid > limits.drift else (low, mid)
    d, stable = drift_and_stability(trials, g + high * lift)
    return g + high * lift, d, stable


def check_start(trials, log_gains, limits):
    """One-line errors before any long computation: a starting controller that is unstable for an
    arm, or a drift limit that no stiffening within ``MAX_STIFFENING`` meets stably."""
    for i, t in enumerate(trials):
        _, r = _drift_and_radius(t, log_gains)
        if not r[0] < 1.0:
            raise ValueError(
                f"design: the starting controller's loop is unstable for robust_over[{i}] (spectral radius "
                f"{r[0]:.6f} per period, must be < 1): lower its gains"
            )
    g, d, stable = project(trials, log_gains, limits)
    if not stable or (limits.drift is not None and d > limits.drift):
        k = np.exp(g[:2]).round(1).tolist()
        raise ValueError(
            f"design: no controller within the limits: the drift limit {limits.drift} m needs stiffness "
            f"{k} N/m or more, where the loop (with gain margin {STABILITY_MARGIN:g}) is unstable or the drift "
            f"stays at {d:.4g} m; raise the drift limit or lower min_stiffness/min_damping"
        )
    return g
