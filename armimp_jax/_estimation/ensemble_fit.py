"""The classical route to an arm's impedance during a movement (docs/movement.md): ensemble least
squares at each knot, the perturbation as instrument, intervals clustered by repetition. NumPy and
SciPy, on an ``Ensemble``.

What the ensemble tells (docs/model.md, "The arm during a movement"): once the ensemble mean is
subtracted at each sample, what remains of each repetition is its response to its own
perturbation and noise, and the arm's force obeys, exactly (the arm is linear about the common
path, and ``B_h(t)``, ``K_h(t)`` are piecewise linear through the knots)::

    F~ = M_h x~dd + sum_j w_j(t) (B_j x~d + K_j x~) - F~_v + noise

with ``w_j`` the hat function of knot ``j`` (1 at its knot, 0 at its neighbours; the first and last
held flat outside the knots, as ``Profile`` is). The rule, step by step:

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
   error on the mass term alone moved ``K`` by several N/m.
2. **Deviations.** Subtract the ensemble mean of each signal at each sample (the perturbation's too).
3. **Instruments.** The regressors are not independent of the error: the person's own force
   ``F_v`` moves the hand, and the encoder's steps are in ``x`` itself. Ordinary least squares is
   biased by both (measured on the base case, 12 ensembles of 50: ``K`` 10-40% high with the
   person's force alone, 0.5-7% low with the encoder alone). The perturbation is independent of
   both, and drives the motion: its deviations through ``LAGUERRE_ORDER`` Laguerre filters (time
   constant ``LAGUERRE_TIME``), each times each knot's ``w_j``, are the instruments (two-stage least
   squares). On the same ensembles they leave no bias beyond 0.3 of the spread on any knot's
   ``K`` or ``B`` diagonal (``armimp_bench.movement``).
4. **Prewhitening.** ``F_v`` is slow and large: the error is far from white, and equal weights
   waste most of the record's information on ``K``. A first pass's residuals give an AR(``WHITEN``)
   model per force axis (Yule-Walker, pooled over repetitions); its inverse filter, applied to
   every signal of the equation alike (an LTI filter passes through it exactly: the knots'
   weights are inside the columns), whitens the error for the second pass (measured with 8
   Laguerre filters: ``B``'s standard errors 4-5% of its value instead of 17-25%, ``K``'s at
   mid-reach 30% instead of 45%; with the 12 used, ``K``'s are 8-23% by knot, ``B``'s 3-4%).
5. **Intervals clustered by repetition.** The repetitions are independent, the samples within
   one are not: the cluster-robust sandwich ``A^-1 (sum_r s_r s_r^T) A^-1`` (``A = X^_T X^``, ``X^``
   the first stage's fit, ``s_r`` repetition ``r``'s score ``X^_r^T e_r``) times ``(R / (R - 1))^2``:
   one ``R / (R - 1)`` is the usual small-sample correction (CR1 with ``R`` clusters), the other
   restores the share of each repetition's noise that the ensemble mean removed. Intervals use
   Student's t with ``R - 1`` degrees of freedom.

The samples used run from ``window`` before the first knot to ``window`` after the last.
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
# The instruments: the perturbation through this many Laguerre filters of this time constant [s]
# (their reach, about 2 * order * time, spans the loop's memory: the base case's slowest mode
# decays in ~0.2 s). Measured on the base case (50 ensembles of 50): 8 filters gave K's standard
# errors 13-34% by knot, 12 gave 8-23% at the same coverage, 16 and 24 (20 ms) no better.
LAGUERRE_ORDER = 12
LAGUERRE_TIME = 0.01
WHITEN = 20  # the prewhitening AR model's order (20 ms at 1 kHz: the person's force is below 2 Hz)
# Fewer repetitions than this get a warning: the clustered intervals then rest on few degrees of freedom.
FEW_REPETITIONS = 30
# A knot whose perturbation is below this share of the record's is missed by it; so is a knot where
# the instruments explain less than this share of the hand's motion (the first stage's R^2).
MISSED = 0.25
# A window shorter than half of this [s] or of the knots' spacing leaves the first and last knots
# short of samples.
SHORT_SPAN = 0.2
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


def _check(ensemble: Ensemble, knots: np.ndarray, window: float, cutoff: float) -> tuple[int, int]:
    """One-line refusals before any computation; returns the span's samples ``(first, end)`` in the
    trimmed signals (``EDGE`` and the prewhitening's start-up cut at each end)."""
    if not isinstance(ensemble, Ensemble):
        raise ValueError(
            f"estimate_ensemble takes an Ensemble (simulate_ensemble's, or aj.Ensemble(...)), got "
            f"{type(ensemble).__name__}"
        )
    if ensemble.f_delta is None:
        raise ValueError(
            "estimate_ensemble: the ensemble holds no perturbations (f_delta): each repetition's perturbation is "
            "the estimate's instrument; record it with the hand's position and force"
        )
    period, n = ensemble.period, ensemble.samples
    if not 0 < cutoff < 0.5 / period:
        raise ValueError(
            f"estimate_ensemble: cutoff must lie in (0, {0.5 / period:g}) Hz (below Nyquist), got {cutoff!r}"
        )
    half = int(np.floor(window / period + 1e-9)) if window > 0 else 0
    if half < 2:
        raise ValueError(f"estimate_ensemble: window must be at least {2 * period:g} s, got {window!r}")
    first, end = round(knots[0] / period) - half, round(knots[-1] / period) + half + 1
    if first < EDGE + WHITEN or end > n - EDGE:
        raise ValueError(
            f"estimate_ensemble: the samples from {window:g} s before the first knot ({knots[0]:g} s) to {window:g} s "
            f"after the last ({knots[-1]:g} s) leave the record ({(EDGE + WHITEN) * period:g} to "
            f"{(n - 1 - EDGE) * period:g} s usable): record longer before and after the reach, or shorten window="
        )
    reps, unknowns = ensemble.repetitions, 2 + 4 * knots.size
    if reps < unknowns + 1:
        raise ValueError(
            f"estimate_ensemble: {reps} repetitions cannot give intervals for {knots.size} knots: each force axis has "
            f"{unknowns} unknowns (M, and B and K at every knot), and intervals clustered by repetition need at least "
            f"{unknowns + 1} repetitions; record more reaches or ask for fewer knots"
        )
    return first - EDGE, end - EDGE


def _deviations(ensemble: Ensemble, cutoff: float, acquisition: str):
    """Smoothed deviations from the ensemble mean at samples ``EDGE..N-1-EDGE``: position [m],
    velocity [m/s], acceleration [m/s^2], force [N], perturbation [N], each ``(R, N - 2 EDGE, 2)``
    (the module's rule, steps 1-2)."""
    sos = scipy.signal.butter(FILTER_ORDER, cutoff, fs=1.0 / ensemble.period, output="sos")
    x = scipy.signal.sosfiltfilt(sos, ensemble.x, axis=1)
    f = scipy.signal.sosfiltfilt(sos, ensemble.fh, axis=1)
    x, f = x - x.mean(axis=0), f - f.mean(axis=0)
    fd = ensemble.f_delta - ensemble.f_delta.mean(axis=0)
    period, n = ensemble.period, ensemble.samples

    def at(shift):  # x_k+shift for k = EDGE..N-1-EDGE
        return x[:, EDGE + shift : n - EDGE + shift]

    v = (8.0 * (at(1) - at(-1)) - (at(2) - at(-2))) / (12.0 * period)
    if acquisition == "instant":  # (v_k - v_k-1) / L
        v_prev = (8.0 * (at(0) - at(-2)) - (at(1) - at(-3))) / (12.0 * period)
        a = (v - v_prev) / period
    else:
        a = (16.0 * (at(1) + at(-1)) - (at(2) + at(-2)) - 30.0 * at(0)) / (12.0 * period * period)
    return at(0), v, a, f[:, EDGE : n - EDGE], fd[:, EDGE : n - EDGE]


def _hats(times, knots) -> np.ndarray:
    """``(S, J)``: each knot's hat function at ``times`` [s] (held flat outside the knots)."""
    return np.stack([np.interp(times, knots, np.eye(knots.size)[j]) for j in range(knots.size)], axis=1)


def _columns(x, v, a, hats):
    """The design ``(R, S, P)``: the acceleration (M's two columns), then per knot ``j`` the
    velocity and the position times its hat (B_j's and K_j's)."""
    reps, samples, n_knots = x.shape[0], x.shape[1], hats.shape[1]
    design = np.empty((reps, samples, 2 + 4 * n_knots))
    design[:, :, 0:2] = a
    for j in range(n_knots):
        w = hats[None, :, j, None]
        design[:, :, 2 + 4 * j : 4 + 4 * j] = w * v
        design[:, :, 4 + 4 * j : 6 + 4 * j] = w * x
    return design


def _instruments(fd, hats, period: float):
    """``(R, S, 2 LAGUERRE_ORDER J)``: the perturbation's deviations ``fd`` ``(R, S, 2)`` through the
    Laguerre filters, each times each knot's hat (step 3)."""
    pole = np.exp(-period / LAGUERRE_TIME)
    y = scipy.signal.lfilter([np.sqrt(1.0 - pole * pole)], [1.0, -pole], fd, axis=1)
    basis = []
    for _ in range(LAGUERRE_ORDER):
        basis.append(y)
        y = scipy.signal.lfilter([-pole, 1.0], [1.0, -pole], y, axis=1)
    basis = np.concatenate(basis, axis=2)
    return np.concatenate([hats[None, :, j, None] * basis for j in range(hats.shape[1])], axis=2)


class _Pass(NamedTuple):
    """One two-stage least-squares fit of one force axis: ``beta`` ``(P,)``, its clustered
    covariance ``(P, P)``, the residuals ``(R, S)`` and, per column of the design, the share of it
    the instruments explain ``(P,)`` (the first stage's R^2)."""

    beta: np.ndarray
    covariance: np.ndarray
    residuals: np.ndarray
    explained: np.ndarray


def _two_stage(design, f, instruments) -> _Pass:
    """Two-stage least squares of ``f`` ``(R, S)`` on ``design`` ``(R, S, P)`` with ``instruments``
    ``(R, S, Q)``, and its covariance clustered by repetition (steps 3 and 5)."""
    reps, samples, p = design.shape
    z, x = instruments.reshape(reps * samples, -1), design.reshape(reps * samples, p)
    fitted = z @ scipy.linalg.solve(z.T @ z, z.T @ x, assume_a="sym")
    beta = np.linalg.solve(fitted.T @ x, fitted.T @ f.reshape(-1))
    residuals = (f.reshape(-1) - x @ beta).reshape(reps, samples)
    explained = np.sum(fitted * fitted, axis=0) / np.sum(x * x, axis=0)
    fitted = fitted.reshape(reps, samples, p)
    scores = np.einsum("rsp,rs->rp", fitted, residuals)
    inv = np.linalg.inv(np.einsum("rsp,rsq->pq", fitted, fitted))
    scale = (reps / (reps - 1)) ** 2  # CR1, and the ensemble mean's share (module docstring)
    return _Pass(beta, scale * inv @ (scores.T @ scores) @ inv, residuals, explained)


def _whitener(residuals) -> np.ndarray:
    """The FIR ``(1, -a_1, ..., -a_p)`` that whitens an AR(``WHITEN``) model of ``residuals``
    ``(R, S)`` (Yule-Walker, the autocovariances pooled over repetitions; step 4)."""
    r = np.array([np.sum(residuals[:, k:] * residuals[:, : residuals.shape[1] - k]) for k in range(WHITEN + 1)])
    return np.concatenate([[1.0], -scipy.linalg.solve_toeplitz(r[:WHITEN], r[1:])])


def _fit_axis(design, f, instruments, span: slice) -> tuple[_Pass, np.ndarray]:
    """One force axis: a first pass over ``span``, then the second on every signal prewhitened by
    the first's residuals (the filter runs from the trimmed record's start, so that ``span``'s
    samples are whole; step 4). Returns the second pass and the first's ``explained``."""
    first = _two_stage(design[:, span], f[:, span], instruments[:, span])
    c = _whitener(first.residuals)
    white = [scipy.signal.lfilter(c, [1.0], s, axis=1)[:, span] for s in (design, f, instruments)]
    return _two_stage(*white), first.explained


def _misses(sound: Ensemble, knots, fd, hats, moved, span: slice) -> list[str]:
    """The knots the perturbation misses (``MISSED``): too little of it in the knot's hat, or too
    little of the hand's motion there that follows it (the first stage's R^2 of the knot's
    position columns)."""
    out = []
    overall = np.sqrt(np.mean(fd**2))  # the perturbation's typical size: over the whole record
    for j, t in enumerate(knots):
        w = hats[span, j][None, :, None]
        local = np.sqrt(np.sum(w * fd[:, span] ** 2) / (fd.shape[0] * 2 * np.sum(w)))
        share = local / overall if overall > 0 else 0.0
        follows = moved[j]
        if share < MISSED or follows < MISSED:
            why = (
                f"the perturbation there is {100 * share:.0f}% of its typical size"
                if share < MISSED
                else f"it explains {100 * follows:.0f}% of the hand's motion there"
            )
            out.append(
                f"the perturbation misses the knot at {t:g} s: {why}, so that knot's B and K rest on the person's own "
                "force and noise; perturb through the whole reach, or more strongly"
            )
    return out


def _warnings(sound: Ensemble, knots, window: float, misses, dropped: int) -> list[str]:
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
    least = min(spacing, SHORT_SPAN) / 2
    if window < least:
        out.append(
            f"the window (+-{1000 * window:g} ms) is short: the first and last knots rest on fewer samples than the "
            f"others (their B and K on {1000 * window:g} ms beyond them); widen window= to {1000 * least:g} ms or more"
        )
    return out + misses


def estimate_ensemble(
    ensemble: Ensemble,
    *,
    knots=None,
    window: float = 0.1,
    cutoff: float = 30.0,
    acquisition: str = "instant",
) -> EnsembleFit:
    """The arm's ``M``, and ``B`` and ``K`` at each knot, from an ensemble of repetitions of one
    reach, with intervals clustered by repetition (the module docstring's rule).

    Args:
        ensemble: an ``Ensemble`` (``simulate_ensemble``'s, or a lab's) with its perturbations;
            diverged repetitions are left out.
        knots: the times [s] at which to estimate ``B`` and ``K``, increasing; default: the
            simulated arm's stiffness profile's knots. Between knots ``B`` and ``K`` are linear.
        window: how far [s] before the first knot and after the last the samples reach (default
            0.1 s; ``B`` and ``K`` are taken constant there).
        cutoff: the smoothing low-pass [Hz] before differentiation (default 30 Hz): above the
            perturbation's band, below where sensor noise dominates.
        acquisition: ``"instant"`` (default: forces sampled just before the robot's new
            command, as ``simulate`` records them) or ``"plain"`` (a continuous force): which
            acceleration the force holds (module docstring, step 1).

    Refused in one line, before any computation: an ensemble without its perturbations, samples
    that leave the record, fewer repetitions than a force axis's unknowns plus one (``3 + 4 J``
    for ``J`` knots), a cutoff at or above the Nyquist rate. Warned of (``EnsembleFit.warnings``, in
    a lab's terms): too few repetitions, a window too short, a perturbation that misses a knot.
    """
    knots = _knots(ensemble, knots)
    check_choice("acquisition", acquisition, ("instant", "plain"))
    sound = ensemble.sound() if isinstance(ensemble, Ensemble) else ensemble
    span = slice(*_check(sound, knots, window, cutoff))
    x, v, a, f, fd = _deviations(sound, cutoff, acquisition)
    hats = _hats(sound.times[EDGE : sound.samples - EDGE], knots)
    design, instruments = _columns(x, v, a, hats), _instruments(fd, hats, sound.period)
    fits, explained = zip(*[_fit_axis(design, f[:, :, i], instruments, span) for i in range(2)])
    moved = [float(np.min(explained[0][4 + 4 * j : 6 + 4 * j])) for j in range(knots.size)]  # K_j's columns
    beta = np.stack([p.beta for p in fits], axis=1)  # (P, 2)
    se = np.sqrt(np.stack([np.diag(p.covariance) for p in fits], axis=1))

    def unpack(values, first):
        return np.stack([values[first + 4 * j : first + 4 * j + 2].T for j in range(knots.size)])

    misses = _misses(sound, knots, fd, hats, moved, span)
    return EnsembleFit(
        knots=knots,
        mass=beta[0:2].T,
        damping=unpack(beta, 2),
        stiffness=unpack(beta, 4),
        mass_se=se[0:2].T,
        damping_se=unpack(se, 2),
        stiffness_se=unpack(se, 4),
        dof=sound.repetitions - 1,
        covariance=np.stack([p.covariance for p in fits]),
        repetitions=sound.repetitions,
        window=float(window),
        cutoff=float(cutoff),
        warnings=tuple(_warnings(sound, knots, window, misses, ensemble.repetitions - sound.repetitions)),
    )
