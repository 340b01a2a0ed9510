"""Experiment design on the Cramér-Rao bound (``design(..., method="bound")``).

Where the loop is near-linear (IMBIC with or without friction, PD without), the criterion is
the bound of ``bound.fisher_information``: deterministic, cheap, and differentiable in the
perturbation's spectrum and in the controller's gains, so both are designed together by
projected gradient steps (optax's Adam on the log of the spectrum and of the diagonal gains;
after each step the gains are projected onto what the clinician allows:
``controller_design.project``). Every other limit holds by construction:

- the perturbation's RMS and peak force: ``design._limited_signal``;
- its peak hand displacement: the signal is scaled to the limit on the linearised loop of
  every arm (inside the criterion, so the gradient sees the trade-off), and the returned
  design is re-scaled by bisection on the full simulation (friction and kinematics included);
- the drift, the minimum gains and stability with margin: the projection.

The answer in minutes is the bound's record length for the precision asked, worst over the
arms (``Bound.record_for``: the bound falls as one over the square root of the record).

The bound leaves out the joints' Coulomb friction, which costs ``identify`` information that
differs by arm and entry. ``calibrate`` rounds measure it: ``predict_se`` (``identify``'s
statistic, simulated through the friction) over the bound gives each arm's and target's ratio
at the design, and the next round designs on the bound times those ratios, held fixed, from
there (``design_calibrated``). Its answer adds the minutes ``predict_se`` gives on the
returned design, on draws of their own (the rounds' draws chose the design).
"""

from __future__ import annotations

import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .._identification import layout as lay
from .._identification import linear
from .._identification.bound import _fisher, crlb
from .._identification.precision import record_minutes
from .._identification.predict import predict_se
from .._pytree import replace_unchecked
from . import controller_design as cd
from .criterion import DesignPlan, _aggregate, relative_se
from .descent import descend
from .limits import _displacement_gain, _limited_signal, _peak_displacement

BACKTRACKS = 6  # halvings of a step whose gains leave the loop unstable before it is skipped


class BoundDesign(NamedTuple):
    """``design(..., method="bound")``'s answer (host values).

    ``family`` and ``signal`` ``(N, 2)`` [N]: the designed perturbation at its limited level
    (``start_signal``: the start's, under the start's controller);
    ``trials``: the ``robust_over`` trials with the designed controller; ``controller``: its
    record (``controller_design.controller_record``); ``bounds``: per trial the ``Bound`` of the
    design; ``start_bounds``: of the start; ``minutes`` / ``start_minutes``: per trial the record
    for ``precision`` at 95% on the targets; ``criterion_before`` / ``criterion_after``: the
    largest relative SE bound of the targets over the trials on ``limits.record``; ``trace``:
    the smoothed criterion per step (in a calibrated round, the bound times that round's
    ratios: the rounds' values are not on one scale); ``achieved``: RMS and peak force per axis [N], the largest
    peak hand displacement [m] (full simulation) and drift [m] over the trials; ``time_s``.
    With ``calibrate`` rounds (else ``None``): ``predicted_minutes``, per trial the minutes of
    ``predict_se`` (through the friction) on the returned design; ``friction_ratio`` ``(T, k)``:
    its relative SEs of the targets over the bound's there. ``targets``: the labels of the
    entries the criterion weighs (the order of ``friction_ratio``'s columns)."""

    family: object
    signal: np.ndarray
    start_signal: np.ndarray
    trials: list
    controller: dict
    bounds: list
    start_bounds: list
    minutes: list
    start_minutes: list
    criterion_before: float
    criterion_after: float
    trace: list
    achieved: dict
    time_s: float
    predicted_minutes: list | None = None
    friction_ratio: np.ndarray | None = None
    targets: tuple = ()


def _linear_peak(trial, f):
    y = linear.respond(linear.linearise(trial), f)
    return jnp.sqrt(jnp.max(y[:, 0] ** 2 + y[:, 1] ** 2))  # sqrt after max: its derivative at 0 is infinite


def _objective(z, offsets, family, trials, layout, idx, limits, aggregate, key, n, period, design_gains, smooth=True):
    """The smoothed worst (or mean) log relative SE bound of the targets, each trial's shifted by
    its row of ``offsets`` ``(T, k)`` (a calibration's log ratios; zeros: the bound alone), with
    the signal scaled to the displacement limit on every arm's linear loop; aux: that scale."""
    fam = replace_unchecked(family, shape=jnp.exp(z["shape"]))
    f = _limited_signal(fam, key, n, limits, period)
    looped = [cd.with_gains(t, z["gains"]) if design_gains else t for t in trials]
    scale = jnp.asarray(1.0)
    if limits.peak_displacement is not None:
        peak = jnp.max(jnp.stack([_linear_peak(t, f) for t in looped]))
        scale = jnp.minimum(1.0, limits.peak_displacement / peak)
    per_trial = []
    for k, t in enumerate(looped):
        info = _fisher(layout, t, f * scale)
        cov = jnp.linalg.inv(info)
        values = lay.pack_arm(layout, t)
        sub = jnp.diag(cov)[idx] / values[idx] ** 2
        per_trial.append(0.5 * jnp.log(sub) + offsets[k])
    return jnp.log(_aggregate(per_trial, "max_relative_se", aggregate, smooth)), scale


def _bounds(trials, f, free, precision, entries):
    bounds = [crlb(t, f, free=free) for t in trials]
    minutes = [
        record_minutes(b.seconds, max(b.relative(entries).values()), precision) if b.near_linear else float("nan")
        for b in bounds
    ]
    return bounds, minutes


def _worst(bounds, entries, ratios=None):
    """The largest relative SE bound of ``entries`` over the trials, each times its ``ratios``
    ``(T, k)`` (a calibration's; default 1)."""
    ratios = np.ones((len(bounds), len(entries))) if ratios is None else ratios
    return max(float(np.max(np.asarray(list(b.relative(entries).values())) * r)) for b, r in zip(bounds, ratios))


def _step(z, state, opt, value_and_grad, trials, limits, design_gains):
    """One projected Adam step; a step whose gains leave a loop unstable is halved until it does
    not, or, after ``BACKTRACKS`` halvings, moves the spectrum alone. Returns ``(z, state, value)``."""
    (value, _), grad = value_and_grad(z)
    if not (np.isfinite(float(value)) and all(np.all(np.isfinite(np.asarray(g))) for g in grad.values())):
        return z, state, float("nan")
    updates, new_state = opt.update(jax.tree.map(np.asarray, grad), state, z)  # z: for an optimizer that reads it
    new_state = jax.tree.map(np.asarray, new_state)
    new = {k: np.asarray(z[k] + updates[k]) for k in z}
    if not design_gains:
        return new, new_state, float(value)
    step = np.asarray(updates["gains"])
    for _ in range(BACKTRACKS):
        gains, _, stable = cd.project(trials, z["gains"] + step, limits)
        if stable:
            return {**new, "gains": gains}, new_state, float(value)
        step = 0.5 * step
    return {**new, "gains": np.asarray(z["gains"])}, new_state, float(value)


def design_on_bound(plan: DesignPlan, family, *, design_gains: bool, precision: float, ratios=None) -> BoundDesign:
    """The design loop (``design`` checks the inputs first), from ``plan.trials``' gains and
    ``family``'s shape; ``ratios`` ``(T, k)``: a calibration's (default: the bound alone)."""
    t_start = time.perf_counter()
    trials, layout, limits, aggregate = plan.trials, plan.layout, plan.limits, plan.aggregate
    period = trials[0].period
    n = limits.n_samples(period)
    family_key = jax.random.split(plan.key)[0]
    gains0 = cd.initial_log_gains(trials[0])
    if design_gains:
        gains0 = cd.check_start(trials, gains0, limits)
    start_trials = [cd.with_gains(t, gains0) if design_gains else t for t in trials]
    idx = np.asarray(plan.idx)
    ratios = np.ones((len(trials), len(idx))) if ratios is None else np.asarray(ratios)

    def fun(z, offsets, smooth=True):
        return _objective(
            z, offsets, family, trials, layout, idx, limits, aggregate, family_key, n, period, design_gains, smooth
        )

    # the ratios enter as an argument, not as constants folded into the program: the gradient
    # test varies them on one compiled program (each round's closure still compiles its own)
    compiled = jax.jit(jax.value_and_grad(fun, has_aux=True))
    offsets = jnp.asarray(np.log(ratios))

    def value_and_grad(z):
        return compiled(z, offsets)

    shape0 = np.asarray(family.shape)
    z = {"shape": np.log(np.maximum(shape0, 1e-6 * shape0.max())), "gains": np.asarray(gains0)}
    opt = plan.optimizer
    trace = []

    def step(carry, i):
        z, state, value = _step(*carry, opt, value_and_grad, trials, limits, design_gains)
        trace.append(float(np.exp(value)) if np.isfinite(value) else float("nan"))
        return z, state

    def after(carry, i):
        if plan.progress is not None:
            plan.progress(i + 1, plan.steps, trace[-1])

    z, _ = descend((z, jax.tree.map(np.asarray, opt.init(z))), step, plan.steps, after=after)
    entries = [layout.labels()[i] for i in plan.idx]
    designed = _Designed(z, trace, ratios)
    return _assemble(
        designed,
        family,
        trials,
        start_trials,
        plan.free,
        limits,
        family_key,
        n,
        period,
        design_gains,
        precision,
        entries,
        t_start,
    )


class _Designed(NamedTuple):
    """What the loop hands to ``_assemble``: the last point ``z``, the criterion per step, and the
    calibration ratios the loop weighed the bound by."""

    z: dict
    trace: list
    ratios: np.ndarray


def friction_ratios(bounds, trials, f, free, entries, *, draws: int, key):
    """``(bound, predicted)``, each ``(T, k)``: per trial the relative SEs of ``entries`` that its
    Cramér-Rao bound in ``bounds`` gives (``crlb`` under ``f``, as a ``BoundDesign`` holds them)
    and that ``predict_se`` gives (``identify``'s statistic, simulated through the trial's
    friction, ``draws`` draws from ``key``) under ``f`` ``(N, 2)`` [N]."""
    bound, predicted = [], []
    for k, (b, t) in enumerate(zip(bounds, trials, strict=True)):
        if not b.near_linear:
            raise ValueError(f"design: calibrate needs a bound at every arm; robust_over[{k}]: {b.message}")
        pred = predict_se(t, f, free=free, draws=draws, key=key)
        rel = relative_se(pred, t, free=free, targets=entries)
        if bool(pred.diverged) or not np.all(np.isfinite(list(rel.values()))):
            raise ValueError(f"design: calibrate's predict_se diverged or is not finite at robust_over[{k}]")
        bound.append([b.relative(entries)[e] for e in entries])
        predicted.append([rel[e] for e in entries])
    return np.asarray(bound), np.asarray(predicted)


def design_calibrated(
    plan: DesignPlan, family, *, design_gains: bool, precision: float, rounds: int, draws: int
) -> BoundDesign:
    """The bound's design, then ``rounds`` rounds calibrated through the friction (module
    docstring); the start, its bounds and minutes are the first round's, the trace runs on.
    ``rounds == 0``: the bound's design alone."""
    if rounds == 0:
        return design_on_bound(plan, family, design_gains=design_gains, precision=precision)
    t_start = time.perf_counter()
    entries = [plan.layout.labels()[i] for i in plan.idx]
    round_key, final_key = jax.random.split(jax.random.split(plan.key, 3)[2])
    first = design_on_bound(
        plan._replace(progress=_counted(plan.progress, 0, rounds + 1)),
        family,
        design_gains=design_gains,
        precision=precision,
    )
    result, trace = first, list(first.trace)
    for r in range(1, rounds + 1):
        # the rounds' draws are common to all of them; the final prediction's are its own
        bound, predicted = friction_ratios(
            result.bounds, result.trials, result.signal, plan.free, entries, draws=draws, key=round_key
        )
        step_plan = plan._replace(trials=result.trials, progress=_counted(plan.progress, r, rounds + 1))
        result = design_on_bound(
            step_plan, result.family, design_gains=design_gains, precision=precision, ratios=predicted / bound
        )
        trace += result.trace
    bound, predicted = friction_ratios(
        result.bounds, result.trials, result.signal, plan.free, entries, draws=draws, key=final_key
    )
    seconds = result.signal.shape[0] * plan.trials[0].period
    return result._replace(
        start_signal=first.start_signal,
        start_bounds=first.start_bounds,
        start_minutes=first.start_minutes,
        criterion_before=first.criterion_before,
        trace=trace,
        predicted_minutes=[record_minutes(seconds, float(np.max(p)), precision) for p in predicted],
        friction_ratio=predicted / bound,
        time_s=time.perf_counter() - t_start,
    )


def _counted(progress, done: int, total: int):
    """``progress`` called with the steps counted over ``total`` design rounds (``done`` before)."""
    if progress is None:
        return None

    def report(step, steps, value):
        progress(done * steps + step, total * steps, value)

    return report


def _assemble(
    designed, family, trials, start_trials, free, limits, key, n, period, design_gains, precision, entries, t_start
):
    """The returned design: the signal re-scaled to the displacement limit on the full simulation
    of every arm, the bounds before and after, and what was achieved."""

    def finish(fam, looped):
        gain = _displacement_gain(fam, key, n, limits, looped, period)
        f = np.asarray(_limited_signal(fam, key, n, limits, period, gain))
        return f, *_bounds(looped, f, free, precision, entries)

    z, trace, ratios = designed
    designed = replace_unchecked(family, shape=np.exp(z["shape"]))
    looped = [cd.with_gains(t, z["gains"]) for t in trials] if design_gains else list(trials)
    f0, before, start_minutes = finish(family, start_trials)
    f, after, minutes = finish(designed, looped)
    if _worst(after, entries, ratios) > _worst(before, entries, ratios):  # never worse than its start
        designed, looped, f, after, minutes = family, start_trials, f0, before, start_minutes
    drift = max(float(linear.drift(t)) for t in looped)
    peak = max(float(_peak_displacement(t, jnp.asarray(f))[0]) for t in looped)
    achieved = dict(
        rms_force=np.sqrt(np.mean(f**2, axis=0)).tolist(),
        peak_force=np.max(np.abs(f), axis=0).tolist(),
        peak_displacement=peak,
        drift=drift,
        # the limit holds on the noise-free simulation; the person's own force moves the hand too
        peak_displacement_plus_3_drift=peak + 3.0 * drift,
    )
    return BoundDesign(
        family=replace_unchecked(designed, rms=np.sqrt(np.mean(f**2, axis=0))),
        signal=f,
        start_signal=f0,
        trials=looped,
        controller=cd.controller_record(looped[0]),
        bounds=after,
        start_bounds=before,
        minutes=minutes,
        start_minutes=start_minutes,
        criterion_before=_worst(before, entries),
        criterion_after=_worst(after, entries),
        trace=trace,
        achieved=achieved,
        time_s=time.perf_counter() - t_start,
        targets=tuple(entries),
    )
