"""The record a designed experiment is written at, its numbers there, and its Monte Carlo
check: the spread of ``identify``'s estimates over new noise against the predictions.

- ``predicted_record(doc, ...)``: the record [s] the design's own answer names (what the
  design script writes by default);
- ``validation_signal(result, limits, record, ...)``: the designed perturbation at a record,
  within the same limits;
- ``at_record(result, signal, ...)``: the design's answer at that signal: the Cramér-Rao bound
  (and, calibrated, ``predict_se``) of every arm with the designed controller, the minutes,
  the limits achieved; so every number ``design.json`` holds is what ``crlb`` or
  ``predict_se`` gives on the controller and the signal written;
- ``checked_scale(design_signal, checked_signal)``: the factor on predicted SEs at another signal;
- ``validate(signal, trials, free, seeds=...)``: simulate and identify under new noise;
- ``truth(trial, free)``: the values the estimates are scored against.

``design_experiment`` sets the spread against the predictions in ``design.json``.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

from ..._design.bound_design import BoundDesign, friction_ratios
from ..._design.limits import Limits, _peak_displacement, limited_signal
from ..._identification.bound import crlb
from ..._identification.identify import identify
from ..._identification.indirect import IDENTIFY_NUMERICS
from ..._identification.layout import make_layout, natural, pack
from ..._identification.precision import record_minutes
from ..._identification.predict import predict_se
from ..._simulate import simulate


def truth(trial, free) -> np.ndarray:
    """The true values of ``free``'s entries in ``trial`` (the natural vector, in label order)."""
    layout = make_layout(free)
    return np.asarray(natural(layout, pack(layout, trial), trial))


def predicted_record(doc: dict, *, design_record: float, precision: float) -> float:
    """The record [s] a design's answer says meets ``precision`` (relative, at 95%) on every
    target at every arm, rounded up to a whole second: ``predict_se``'s minutes through the
    friction where the design was calibrated, else the bound's minutes (which leave any friction
    out), else (Monte Carlo) the largest predicted relative SE at ``design_record`` [s] by the
    ``1 / sqrt(T)`` law. Never shorter than ``design_record``: the law is checked upward, on
    at least the record the design saw. ``doc`` is ``result_dict``'s."""
    rows = doc["trials"]
    if doc["method"] == "bound":
        per_arm = [r.get("predicted_minutes", r["minutes_after"]) for r in rows]
        lost = [r.get("label", "an arm") for r, m in zip(rows, per_arm, strict=True) if not math.isfinite(m)]
        if lost:  # crlb's NaN: the designed loop is not near-linear there (stick-slip), so no bound holds
            raise ValueError(
                f"design: no Cramér-Rao bound holds for the designed experiment at {', '.join(lost)} (the joints' "
                "friction makes the hand stick and slip): no record can be predicted on the bound; lower the "
                "friction or raise the force, or design with method 'monte_carlo' (through the friction)"
            )
        minutes = max(per_arm)
    else:
        worst = max(max(r["relative_se_after"].values()) for r in rows)
        minutes = record_minutes(design_record, worst, precision)
    return float(max(math.ceil(60.0 * minutes - 1e-9), design_record))


def validation_signal(result, limits: Limits, record: float, *, trials, key) -> np.ndarray:
    """The designed perturbation at ``record`` [s]: the design's own signal at its record,
    else its family's at the new length, within the same limits (``limited_signal`` with the
    design's family key ``jax.random.split(key)[0]``, the hand's displacement checked on every
    trial's full simulation at that length)."""
    if record == limits.record:
        return np.asarray(result.signal)
    longer = dataclasses.replace(limits, record=record)
    return limited_signal(result.family, longer, key=jax.random.split(key)[0], trials=trials)


def at_record(result, signal, trials, *, free, targets, precision: float, draws: int, key):
    """``result`` (a ``BoundDesign`` or a Monte Carlo ``Design`` of ``trials``, the designed
    controller's) with its signal replaced by ``signal`` ``(N, 2)`` [N] and every number
    recomputed there: the force and the noise-free displacement achieved; a bound design's
    ``bounds`` (``crlb``) and ``minutes`` (``record_minutes`` at ``precision``) and, where it
    was calibrated, ``predict_se``'s (``draws`` draws from ``key``: ``friction_ratio``,
    ``predicted_minutes``); a Monte Carlo design's ``after`` (``predict_se``). The start's
    numbers (``start_*``, ``before``) and the optimisation's (``trace``, ``criterion_*``) stay
    the design record's. ``result`` itself where ``signal`` is its own."""
    signal = np.asarray(signal)
    if signal.shape == np.shape(result.signal) and np.array_equal(signal, result.signal):
        return result
    seconds = signal.shape[0] * trials[0].period
    achieved = dict(
        result.achieved,
        rms_force=np.sqrt(np.mean(signal**2, axis=0)).tolist(),
        peak_force=np.max(np.abs(signal), axis=0).tolist(),
        peak_displacement=max(float(_peak_displacement(t, jnp.asarray(signal))[0]) for t in trials),
    )
    if "drift" in achieved:
        achieved["peak_displacement_plus_3_drift"] = achieved["peak_displacement"] + 3.0 * achieved["drift"]
    if not isinstance(result, BoundDesign):
        after = [predict_se(t, signal, free=free, draws=draws, key=key) for t in trials]
        return result._replace(signal=signal, after=after, achieved=achieved)
    bounds = [crlb(t, signal, free=free) for t in trials]
    minutes = [
        record_minutes(seconds, max(b.relative(targets).values()), precision) if b.near_linear else float("nan")
        for b in bounds
    ]
    out = result._replace(signal=signal, bounds=bounds, minutes=minutes, achieved=achieved)
    if result.predicted_minutes is None:
        return out
    bound, predicted = friction_ratios(bounds, trials, signal, free, targets, draws=draws, key=key)
    return out._replace(
        friction_ratio=predicted / bound,
        predicted_minutes=[record_minutes(seconds, float(np.max(p)), precision) for p in predicted],
    )


def checked_scale(design_signal, checked_signal) -> float:
    """What a design's predicted SEs become on ``checked_signal`` ``(N, 2)`` [N]: times
    ``sqrt(T_design / T)`` (the ``1 / sqrt(T)`` law) and, where the displacement check at the
    new length lowered the level, times the largest per-axis RMS ratio (an SE goes as one
    over the level in a near-linear loop)."""
    d, c = np.asarray(design_signal), np.asarray(checked_signal)
    level = float(np.max(np.sqrt(np.mean(d**2, axis=0) / np.mean(c**2, axis=0))))
    return math.sqrt(d.shape[0] / c.shape[0]) * max(1.0, level)


def validate(signal, trials, free, *, seeds: int, draws: int = 32, progress=None) -> list[dict]:
    """Per trial: ``seeds`` recordings under new noise with ``signal``, each identified from the
    truth; returns per trial the spread ``(n,)`` (natural entries) of the estimates of the
    fits that converged, and how many recordings diverged and how many fits converged (the
    rest are counted, never scored). ``progress()`` is called after each recording."""
    sim = jax.jit(simulate, static_argnames="numerics")
    out = []
    for i, trial in enumerate(trials):
        estimates, converged, diverged = [], 0, 0
        for seed in range(seeds):
            rec = sim(trial, signal, key=jax.random.key(50_000 + 1000 * i + seed), numerics=IDENTIFY_NUMERICS)
            if bool(rec.diverged):
                diverged += 1
            else:
                res = identify(trial, signal, rec.x, rec.fh, free=free, draws=draws, key=jax.random.key(seed))
                if res.converged:
                    converged += 1
                    estimates.append(np.concatenate([np.ravel(res.values[n]) for n in free]))
            if progress is not None:
                progress()
        if len(estimates) < 2:
            raise RuntimeError(
                f"validate: only {len(estimates)} of {seeds} fits converged for trial {i}; no spread to report"
            )
        e = np.stack(estimates)
        out.append(
            dict(
                recordings=seeds,
                diverged=diverged,
                converged=converged,
                spread=e.std(axis=0, ddof=1),
                mean_error=e.mean(axis=0) - truth(trial, free),
            )
        )
    return out
