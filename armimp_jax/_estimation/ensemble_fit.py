"""The classical route to an arm's impedance during a movement (docs/movement.md): ensemble least
squares at each knot, with intervals clustered by repetition. NumPy and SciPy, on an ``Ensemble``.

What the ensemble tells (docs/model.md, "The arm during a movement"): once the ensemble mean is
subtracted at each sample, what remains of each repetition is its response to its own
perturbation and noise, and the arm's force obeys, exactly (the arm is linear about the common path)::

    F~ = M_h x~dd + B_h(t) x~d + K_h(t) x~ - F~_v + noise

The rule, step by step:

1. **Smoothing and differentiation.** ``x`` and ``F_h`` of every repetition go through the same
   zero-phase low-pass (4th-order Butterworth at ``cutoff``, forward and backward: SciPy's
   ``sosfiltfilt``). The velocity ``v_k`` is the five-point central difference of the smoothed
   position, ``(8 (x_k+1 - x_k-1) - (x_k+2 - x_k-2)) / 12 L``. The acceleration depends on the
   ``acquisition``: ``"instant"`` (default, the simulator's) is ``(v_k - v_k-1) / L``, the mean
   acceleration over the period that ends at ``t_k``: a force sampled just before the robot's new
   command holds that one, not a central second difference (which puts a half-sample lag on ``M``
   that reads as ``M w^2 L / 2`` of extra damping, 4 N s/m on the base case's ``B_xx``, as
   ``fit_impedance``'s ``"instant"`` model says); ``"plain"`` is the five-point central second
   difference, for a continuous force. Five points, not three: the stiffness is a small part of
   the force at the perturbation's frequencies, and a three-point difference's ``(w L)^2 / 6``
   error on the mass term alone moved ``K`` by several N/m. Unsmoothed, a 2^18-count encoder's
   steps alone make a 1 kHz acceleration noisier than the perturbed motion.
2. **Deviations.** Subtract the ensemble mean of each signal at each sample.
3. **Windows.** Around each knot ``t_j`` take the samples ``|t - t_j| <= window``. In each window
   each repetition's own intercept and slope are removed from every signal (a least-squares
   line per repetition and window): the person's own force ``F_v`` is slow (below 2 Hz in the
   model), so within a short window it is nearly a line, and left in it would bias ``K`` low,
   because it also moves the hand.
4. **Least squares.** One regression over all windows and repetitions, per force axis:
   ``M`` shared by every knot, ``B_j`` and ``K_j`` by knot ``j``'s window.
5. **Intervals clustered by repetition.** The repetitions are independent, the samples within
   one are not: the cluster-robust sandwich ``A^-1 (sum_r s_r s_r^T) A^-1`` (``A = X^T X``,
   ``s_r`` repetition ``r``'s score ``X_r^T e_r``) times ``(R / (R - 1))^2``: one ``R / (R - 1)``
   is the usual small-sample correction (CR1 with ``R`` clusters), the other restores the share
   of each repetition's noise that the ensemble mean removed. Intervals use Student's t with
   ``R - 1`` degrees of freedom.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import scipy.linalg
import scipy.signal
import scipy.stats

from .._checks import check_choice
from .ensemble import Ensemble

FILTER_ORDER = 4  # the zero-phase low-pass's order (applied twice: forward and backward)
EDGE = 3  # samples at each end of the record that the differences need
# Fewer repetitions than this get a warning: the clustered intervals then rest on few degrees of freedom.
FEW_REPETITIONS = 30
# A window that keeps less than this share of the hand's perturbed motion once each repetition's
# line is removed is too short for its knot.
KEPT_MOTION = 0.25
# A knot whose perturbation (or, unknown, the hand's perturbed motion) is below this share of the
# record's (median over knots, for the motion) is missed by it.
MISSED = 0.25
PARAMETERS = (("M", "mass", "kg"), ("B", "damping", "N s/m"), ("K", "stiffness", "N/m"))


class EnsembleFit(NamedTuple):
    """M, and B and K at every knot, from an ensemble (NumPy; ``estimate_ensemble``).

    ``knots`` ``(J,)`` [s]; ``mass`` ``(2, 2)`` [kg]; ``damping`` ``(J, 2, 2)`` [N s/m] and
    ``stiffness`` ``(J, 2, 2)`` [N/m], indexed ``[knot, output, input]`` (``F_h = M xdd + B xd +
    K x``); ``mass_se``, ``damping_se``, ``stiffness_se``: their standard errors (clustered by
    repetition), same shapes and units. ``dof``: the intervals' degrees of freedom (``R - 1``).
    ``covariance``: ``(2, P, P)``, per force axis the covariance of ``[M row, (B_j row, K_j
    row) for each knot]``. ``repetitions``, ``window`` [s] (half-width), ``cutoff`` [Hz]; ``warnings``:
    one line each, in a lab's terms.
    """

    knots: np.ndarray
    mass: np.ndarray
    damping: np.ndarray
    stiffness: np.ndarray
    mass_se: np.ndarray
    damping_se: np.ndarray
    stiffness_se: np.ndarray
    dof: int
    covariance: np.ndarray
    repetitions: int
    window: float
    cutoff: float
    warnings: tuple

    def interval(self, name: str, level: float = 0.95):
        """Two-sided ``level`` interval of ``"mass"``, ``"damping"`` or ``"stiffness"``: ``(low,
        high)`` arrays, ``value -+ t_(1+level)/2(dof) se``."""
        if name not in ("mass", "damping", "stiffness"):
            raise ValueError(f"EnsembleFit.interval: unknown parameter {name!r}; allowed: mass, damping, stiffness")
        if not 0 < level < 1:
            raise ValueError(f"level must lie strictly between 0 and 1, got {level}")
        half = scipy.stats.t.ppf(0.5 + level / 2, self.dof) * getattr(self, f"{name}_se")
        value = getattr(self, name)
        return value - half, value + half

    def table(self, level: float = 0.95):
        """A pandas table, one row per entry: ``parameter`` (``M``, ``B``, ``K``), ``time`` [s] (NaN
        for M, which every knot shares), ``entry`` (``xx``, ``xy``, ``yx``, ``yy``), ``value``, ``se``,
        ``low``, ``high`` (the ``level`` interval) and ``unit``."""
        import pandas as pd

        rows = []
        for sym, name, unit in PARAMETERS:
            value, se = getattr(self, name), getattr(self, f"{name}_se")
            low, high = self.interval(name, level)
            times = [np.nan] if value.ndim == 2 else list(self.knots)
            for j, t in enumerate(times):
                pick = (lambda a: a) if value.ndim == 2 else (lambda a, j=j: a[j])
                for i in range(2):
                    for k in range(2):
                        row = (sym, t, "xy"[i] + "xy"[k], pick(value)[i, k], pick(se)[i, k], pick(low)[i, k])
                        rows.append((*row, pick(high)[i, k], unit))
        return pd.DataFrame(rows, columns=["parameter", "time", "entry", "value", "se", "low", "high", "unit"])

    def summary(self, level: float = 0.95) -> str:
        """The fit as text: M, then B and K at each knot with their ``level`` intervals, then every warning."""
        pct = f"{100 * level:g}%"
        lines = [
            f"{self.repetitions} repetitions, windows of +-{1000 * self.window:g} ms, smoothing {self.cutoff:g} Hz; "
            f"{pct} intervals clustered by repetition (t, {self.dof} dof)",
            f"{'':22s} {'value':>10s}   {pct} interval",
        ]
        for row in self.table(level).itertuples():
            when = "" if np.isnan(row.time) else f" @t={row.time:g}"
            label = f"{row.parameter}{row.entry}{when} [{row.unit}]"
            lines.append(f"{label:22s} {row.value:10.4g}   [{row.low:.4g}, {row.high:.4g}]")
        lines += [f"warning: {w}" for w in self.warnings]
        return "\n".join(lines)


def _knots(ensemble: Ensemble, knots) -> np.ndarray:
    """The knot times [s]: given, or the simulated arm's stiffness (else damping) profile's."""
    if knots is None:
        arm = getattr(ensemble.trial, "arm", None)
        profiles = (getattr(arm, n, None) for n in ("stiffness", "damping"))
        profile = next((p for p in profiles if hasattr(p, "times")), None)
        if profile is None:
            raise ValueError("estimate_ensemble: pass knots= (the times [s] at which to estimate B and K)")
        knots = profile.times
    t = np.atleast_1d(np.asarray(knots, dtype=np.float64))
    if t.ndim != 1 or t.size < 1 or not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
        raise ValueError(f"estimate_ensemble: knots must be increasing times [s], got {np.asarray(knots).tolist()}")
    return t


def _check(ensemble: Ensemble, knots: np.ndarray, window: float, cutoff: float) -> int:
    """One-line refusals before any computation; returns the window's half-width in samples."""
    if not isinstance(ensemble, Ensemble):
        raise ValueError(
            f"estimate_ensemble takes an Ensemble (simulate_ensemble's, or aj.Ensemble(...)), got "
            f"{type(ensemble).__name__}"
        )
    period, n = ensemble.period, ensemble.samples
    nyquist = 0.5 / period
    if not 0 < cutoff < nyquist:
        raise ValueError(f"estimate_ensemble: cutoff must lie in (0, {nyquist:g}) Hz (below Nyquist), got {cutoff!r}")
    half = int(np.floor(window / period + 1e-9)) if window > 0 else 0
    if half < 2:
        raise ValueError(f"estimate_ensemble: window must be at least {2 * period:g} s (a half-width), got {window!r}")
    centre = np.round(knots / period).astype(int)
    inside = (centre - half >= EDGE) & (centre + half <= n - 1 - EDGE)
    if not inside.all():
        t = knots[~inside][0]
        raise ValueError(
            f"estimate_ensemble: the window around the knot at {t:g} s (+-{window:g} s) leaves the record "
            f"(0 to {(n - 1) * period:g} s): record longer before and after the reach, or move that knot"
        )
    reps = int(ensemble.x.shape[0])
    unknowns = 2 + 4 * knots.size
    if reps < unknowns + 1:
        raise ValueError(
            f"estimate_ensemble: {reps} repetitions cannot give intervals for {knots.size} knots: each force axis has "
            f"{unknowns} unknowns (M, and B and K at every knot), and intervals clustered by repetition need at least "
            f"{unknowns + 1} repetitions; record more reaches or ask for fewer knots"
        )
    return half


def _deviations(ensemble: Ensemble, cutoff: float, acquisition: str):
    """Smoothed deviations from the ensemble mean at samples ``EDGE..N-1-EDGE``: position [m],
    velocity [m/s], acceleration [m/s^2], force [N], each ``(R, N - 2 EDGE, 2)`` (the module's
    rule, steps 1-2)."""
    sos = scipy.signal.butter(FILTER_ORDER, cutoff, fs=1.0 / ensemble.period, output="sos")
    x = scipy.signal.sosfiltfilt(sos, ensemble.x, axis=1)
    f = scipy.signal.sosfiltfilt(sos, ensemble.fh, axis=1)
    x, f = x - x.mean(axis=0), f - f.mean(axis=0)
    period, n = ensemble.period, ensemble.samples

    def at(shift):  # x_k+shift for k = EDGE..N-1-EDGE
        return x[:, EDGE + shift : n - EDGE + shift]

    v = (8.0 * (at(1) - at(-1)) - (at(2) - at(-2))) / (12.0 * period)
    if acquisition == "instant":  # (v_k - v_k-1) / L
        v_prev = (8.0 * (at(0) - at(-2)) - (at(1) - at(-3))) / (12.0 * period)
        a = (v - v_prev) / period
    else:
        a = (16.0 * (at(1) + at(-1)) - (at(2) + at(-2)) - 30.0 * at(0)) / (12.0 * period * period)
    return at(0), v, a, f[:, EDGE : n - EDGE]


def _detrend(signals, bounds):
    """Each signal ``(R, S, 2)`` less its own least-squares line over each block ``[bounds[i],
    bounds[i+1])`` of samples, per repetition and axis."""
    out = [np.array(s) for s in signals]
    for lo, hi in zip(bounds[:-1], bounds[1:]):
        tau = np.arange(hi - lo) - 0.5 * (hi - lo - 1)
        basis = np.stack([np.ones(hi - lo) / np.sqrt(hi - lo), tau / np.sqrt(tau @ tau)], axis=1)  # orthonormal
        for s in out:
            s[:, lo:hi] -= np.einsum("wb,rbc->rwc", basis, np.einsum("vb,rvc->rbc", basis, s[:, lo:hi]))
    return out


def _columns(x, v, a, weights):
    """The design ``(R, S, P)``: the acceleration (M's two columns), then per knot ``j`` the
    velocity and the position weighted by ``weights[:, j]`` (``(S, J)``: B_j's and K_j's)."""
    reps, samples, n_knots = x.shape[0], x.shape[1], weights.shape[1]
    design = np.empty((reps, samples, 2 + 4 * n_knots))
    design[:, :, 0:2] = a
    for j in range(n_knots):
        w = weights[None, :, j, None]
        design[:, :, 2 + 4 * j : 4 + 4 * j] = w * v
        design[:, :, 4 + 4 * j : 6 + 4 * j] = w * x
    return design


def _design(signals, centres, half: int, profile: str, times):
    """The detrended design ``(R, S, P)`` and forces ``(R, S, 2)`` (module docstring, steps 3-4),
    and the detrended positions of each knot's window (for the warnings). ``signals``: ``(x, v,
    a, f)``; ``centres``: the knots' sample indices in them; ``times``: their times [s]."""
    x, v, a, f = signals
    width = 2 * half + 1
    if profile == "window":  # each knot's own constants over its own window
        parts = []
        for j, c in enumerate(centres):
            window = slice(c - half, c + half + 1)
            weights = np.zeros((width, centres.size))
            weights[:, j] = 1.0
            block = _detrend([s[:, window] for s in (x, v, a, f)], [0, width])
            parts.append((_columns(*block[:3], weights), block[3], block[0]))
        return (
            np.concatenate([p[0] for p in parts], axis=1),
            np.concatenate([p[1] for p in parts], axis=1),
            [p[2] for p in parts],
        )
    lo, hi = centres[0] - half, centres[-1] + half + 1
    knots = times[centres]
    weights = np.stack([np.interp(times[lo:hi], knots, np.eye(centres.size)[j]) for j in range(centres.size)], axis=1)
    n_blocks = max(1, (hi - lo) // width)
    bounds = np.linspace(0, hi - lo, n_blocks + 1).round().astype(int)
    design = _columns(x[:, lo:hi], v[:, lo:hi], a[:, lo:hi], weights)
    detrended = _detrend([design, f[:, lo:hi], x[:, lo:hi]], bounds)
    moved = [detrended[2][:, c - half - lo : c + half + 1 - lo] for c in centres]
    return detrended[0], detrended[1], moved


def _regress(design, f):
    """Least squares of ``f`` ``(R, S, 2)`` on ``design`` ``(R, S, P)``: ``beta`` ``(P, 2)`` (per force
    axis ``[M row, (B_j row, K_j row) per knot]``), the cross-product ``A`` ``(P, P)`` and the
    repetitions' scores ``(R, P, 2)``."""
    xtx = np.einsum("rwp,rwq->pq", design, design)
    beta = scipy.linalg.solve(xtx, np.einsum("rwp,rwc->pc", design, f), assume_a="sym")
    return beta, xtx, np.einsum("rwp,rwc->rpc", design, f - design @ beta)


def _warnings(sound: Ensemble, knots, window: float, kept, motion, dropped: int) -> list[str]:
    """The estimate's warnings in a lab's terms (module constants say when)."""
    reps, out = sound.repetitions, []
    if dropped:
        out.append(f"{dropped} repetitions diverged in simulation and were left out")
    if reps < FEW_REPETITIONS:
        out.append(
            f"only {reps} repetitions: the intervals rest on {reps - 1} degrees of freedom and the clustered errors on "
            f"few repetitions; record {FEW_REPETITIONS} or more reaches for intervals to trust"
        )
    spacing = float(np.min(np.diff(knots))) if knots.size > 1 else np.inf
    if 2 * window > spacing:
        out.append(
            f"the windows (+-{1000 * window:g} ms) are longer than the knots' spacing ({1000 * spacing:g} ms): each "
            "knot's B and K average the arm over a window that reaches the next knots, and a profile that turns at "
            "a knot biases them; shorten window="
        )
    for t, share in zip(knots, kept):
        if share < KEPT_MOTION:
            out.append(
                f"the window around the knot at {t:g} s (+-{1000 * window:g} ms) is short: removing each repetition's "
                f"slow drift there keeps {100 * share:.0f}% of the hand's perturbed motion; lengthen window= or "
                "perturb at higher frequencies"
            )
    if sound.f_delta is not None:
        dev = sound.f_delta - sound.f_delta.mean(axis=0)
        overall = np.sqrt(np.mean(dev**2))
        centre = np.round(knots / sound.period).astype(int)
        half = int(np.floor(window / sound.period + 1e-9))
        local = [np.sqrt(np.mean(dev[:, c - half : c + half + 1] ** 2)) for c in centre]
        what, ref = "perturbation", overall
    else:
        local, what, ref = motion, "hand's perturbed motion", float(np.median(motion))
    if not ref > 0:
        out.append(f"the {what} is the same in every repetition: the ensemble mean removes it, leaving no information")
        return out
    for t, value in zip(knots, local):
        if value < MISSED * ref:
            out.append(
                f"the perturbation misses the knot at {t:g} s: the {what} there is {100 * value / ref:.0f}% of its "
                "typical size, so that knot's B and K rest on the person's own force and noise; perturb through the "
                "whole reach"
            )
    return out


def estimate_ensemble(
    ensemble: Ensemble,
    *,
    knots=None,
    window: float = 0.05,
    cutoff: float = 30.0,
    acquisition: str = "instant",
    profile: str = "linear",
) -> EnsembleFit:
    """The arm's ``M``, and ``B`` and ``K`` at each knot, from an ensemble of repetitions of one
    reach, with intervals clustered by repetition (the module docstring's rule).

    Args:
        ensemble: an ``Ensemble`` (``simulate_ensemble``'s, or a lab's); diverged repetitions
            are left out.
        knots: the times [s] at which to estimate ``B`` and ``K``, increasing; default: the
            simulated arm's stiffness profile's knots.
        window: the half-width [s] of the window around each knot (default 50 ms).
        cutoff: the smoothing low-pass [Hz] before differentiation (default 30 Hz): above the
            perturbation's band, below where sensor noise dominates.
        acquisition: ``"instant"`` (default: forces sampled just before the robot's new
            command, as ``simulate`` records them) or ``"plain"`` (a continuous force): which
            acceleration the force holds (module docstring, step 1).

    Refused in one line: a knot whose window leaves the record, fewer repetitions than the
    unknowns of a force axis (``3 + 4 J`` for ``J`` knots), a cutoff at or above the Nyquist rate.
    Warned of (``EnsembleFit.warnings``, in a lab's terms): too few repetitions, a window too
    short or longer than the knots' spacing, a perturbation that misses a knot.
    """
    knots = _knots(ensemble, knots)
    check_choice("acquisition", acquisition, ("instant", "plain"))
    check_choice("profile", profile, ("linear", "window"))
    sound = ensemble.sound() if isinstance(ensemble, Ensemble) else ensemble
    half = _check(sound, knots, window, cutoff)
    signals = _deviations(sound, cutoff, acquisition)
    centres = np.round(knots / sound.period).astype(int) - EDGE  # the signals start at sample EDGE
    times = sound.times[EDGE : sound.samples - EDGE]
    design, f, moved = _design(signals, centres, half, profile, times)
    raw = [signals[0][:, c - half : c + half + 1] for c in centres]
    kept = [float(np.sum(m**2) / np.sum(r**2)) for m, r in zip(moved, raw)]
    motion = [float(np.sqrt(np.mean(m**2))) for m in moved]
    beta, xtx, scores = _regress(design, f)
    reps = scores.shape[0]
    inv = np.linalg.inv(xtx)
    scale = (reps / (reps - 1)) ** 2  # CR1, and the ensemble mean's share (module docstring)
    cov = np.stack([scale * inv @ (scores[:, :, i].T @ scores[:, :, i]) @ inv for i in range(2)])
    se = np.sqrt(np.stack([np.diag(c) for c in cov], axis=1))  # (P, 2)

    def unpack(values, first):
        return np.stack([values[first + 4 * j : first + 4 * j + 2].T for j in range(knots.size)])

    return EnsembleFit(
        knots=knots,
        mass=beta[0:2].T,
        damping=unpack(beta, 2),
        stiffness=unpack(beta, 4),
        mass_se=se[0:2].T,
        damping_se=unpack(se, 2),
        stiffness_se=unpack(se, 4),
        dof=reps - 1,
        covariance=cov,
        repetitions=reps,
        window=float(window),
        cutoff=float(cutoff),
        warnings=tuple(_warnings(sound, knots, window, kept, motion, ensemble.repetitions - reps)),
    )
