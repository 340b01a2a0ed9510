"""Experiment design through ``identify``'s predicted standard errors over noise draws
(``design(..., method="monte_carlo")``): ``design_monte_carlo``.

**Limits are honoured by construction, not penalised**: the family's RMS is set to
``rms_force``, samples beyond ``peak_force`` are clipped and the rest re-scaled until both
hold (so a design uses the whole RMS it is allowed), then the whole signal is scaled down
until the hand's peak displacement in the noise-free simulation of every trial is at most
``peak_displacement`` (``limits.py``). So every signal the optimiser sees, and the one it
returns, meets them (the displacement's gain is re-found every ``REGAIN_EVERY`` steps and
for the returned design). Each step draws fresh noise (a stochastic gradient, optax's Adam):
a design that fitted one fixed set of draws would promise more than the experiment gives.
The last iterate is returned (a cosine-decayed rate with the second half's iterates
averaged was measured worse: docs/experiment_design.md). A step whose draws diverged or
gave a non-finite criterion is skipped and counted. The binding's Jacobian ``A`` is held at
its value for the starting design during the optimisation (it is near the identity and
moves little with the spectrum); the predictions before and after are computed afresh with
``predict_se`` on the same draws, and if the design does not beat the start there, the
start is returned with ``improved=False``: a design never promises less than its start.
"""

from __future__ import annotations

import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from .._identification import indirect
from .._identification import layout as lay
from .._identification.indirect import IDENTIFY_NUMERICS
from .._identification.predict import predict_se
from .._pytree import replace_unchecked
from .criterion import DesignPlan, _aggregate, _criterion_value
from .descent import descend
from .limits import _displacement_gain, _limited_signal, _peak_displacement

REGAIN_EVERY = 10  # steps between re-finding the displacement gain (each is a bisection of forward runs)


class Design(NamedTuple):
    """``design``'s answer (host values): the designed ``family`` (at its limited level) and its
    ``signal`` ``(N, 2)`` [N]; ``start_family`` and ``start_signal`` likewise; ``before`` and
    ``after``: per trial the ``PredictedSE`` of the start and of the design; ``criterion``
    before and after (unsmoothed); ``trace``: the smoothed criterion per optimisation step
    (on that step's draws; NaN for a skipped step); ``achieved``: RMS and peak force per
    axis [N] and the largest peak hand displacement over the trials [m] of the designed
    signal; ``improved``: whether the design beat the start (if not, ``family`` and
    ``signal`` are the start's); ``skipped``: steps skipped for diverged draws; ``time_s``;
    ``start_criteria``: the criterion of each candidate start (the family argument's order);
    ``trials``, ``free`` and ``targets``: the trials designed for, the free parameters and the
    labels of the entries the criterion weighs."""

    family: object
    signal: np.ndarray
    start_family: object
    start_signal: np.ndarray
    before: list
    after: list
    criterion_before: float
    criterion_after: float
    trace: list
    achieved: dict
    improved: bool
    skipped: int
    time_s: float
    start_criteria: list
    trials: list | None = None
    free: tuple = ()
    targets: tuple = ()


class _MonteCarlo(NamedTuple):
    """What the Monte Carlo design holds fixed: the ``plan``; each trial's packed free
    parameters ``points`` and natural ``values``; the record (``n`` samples of ``period`` s);
    the family's and the draws' keys; the draws per step (``n_draws``, ``n_jac`` of them for the
    Jacobian) and per final prediction."""

    plan: DesignPlan
    points: list
    values: list
    n: int
    period: float
    family_key: jax.Array
    draw_key: jax.Array
    n_draws: int
    n_jac: int
    predict_draws: int


def _monte_carlo(plan: DesignPlan, draws: int, predict_draws: int) -> _MonteCarlo:
    trials, layout = plan.trials, plan.layout
    period = trials[0].period
    family_key, draw_key = jax.random.split(plan.key)
    n_draws, n_jac = indirect.draw_counts(trials[0], draws, 2)
    points = [lay.pack(layout, t) for t in trials]
    values = [lay.natural_with_jacobian(layout, p, t)[0] for t, p in zip(trials, points)]
    n = plan.limits.n_samples(period)
    return _MonteCarlo(plan, points, values, n, period, family_key, draw_key, n_draws, n_jac, predict_draws)


def _predictions(mc: _MonteCarlo, f) -> list:
    """``predict_se`` of every trial under ``f``, on the final predictions' draws."""
    key = jax.random.fold_in(mc.draw_key, 2 * 10**6)
    preds = [
        predict_se(t, f, free=mc.plan.free, statistic="welch", key=key, draws=mc.predict_draws, jacobian_draws=8)
        for t in mc.plan.trials
    ]
    bad = [i for i, pr in enumerate(preds) if bool(pr.diverged)]
    if bad:
        raise RuntimeError(f"design: the prediction's simulations diverged for trial {bad[0]} of robust_over")
    return preds


def _plain(mc: _MonteCarlo, preds) -> float:
    """The criterion of predictions, unsmoothed."""
    per_trial = [_criterion_value(pr.covariance, v, mc.plan.idx, mc.plan.criterion) for pr, v in zip(preds, mc.values)]
    return float(_aggregate(per_trial, mc.plan.criterion, mc.plan.aggregate, smooth=False))


def _gain(mc: _MonteCarlo, family):
    """The scale that brings ``family``'s limited signal within the displacement limit."""
    return _displacement_gain(family, mc.family_key, mc.n, mc.plan.limits, mc.plan.trials, mc.period)


def _best_start(mc: _MonteCarlo, candidates):
    """``(family, gain, signal, predictions, criteria)``: the candidate the prediction rates
    best on the same draws (one candidate: no prediction, ``None``), with each one's criterion."""
    starts = []
    for c in candidates:
        g = _gain(mc, c)
        f = _limited_signal(c, mc.family_key, mc.n, mc.plan.limits, mc.period, g)
        preds = _predictions(mc, f) if len(candidates) > 1 else None
        starts.append((c, g, f, preds, _plain(mc, preds) if preds is not None else None))
    family, gain, f0, before, _ = min(starts, key=lambda st: st[4] if st[4] is not None else 0.0)
    return family, gain, f0, before, [st[4] for st in starts]


def _objective(mc: _MonteCarlo, family, f0):
    """The jitted value and gradient of the smoothed criterion in ``log(shape)`` on a step's
    draws (with whether a draw diverged), each trial's binding Jacobian held at the start ``f0``."""
    jac_keys = jax.random.split(jax.random.fold_in(mc.draw_key, 10**6), mc.n_jac)
    # one at a time (block): programs split over the CPU devices must not queue up together
    jacs = [
        jax.block_until_ready(indirect.binding_jacobian(mc.plan.layout, t, p, f0, jac_keys, IDENTIFY_NUMERICS)[0])
        for t, p in zip(mc.plan.trials, mc.points)
    ]
    naturals = [lay.natural_with_jacobian(mc.plan.layout, p, t)[1] for t, p in zip(mc.plan.trials, mc.points)]

    def objective(log_shape, keys, gain, smooth=True):
        fam = replace_unchecked(family, shape=jnp.exp(log_shape))
        f = _limited_signal(fam, mc.family_key, mc.n, mc.plan.limits, mc.period, gain)
        per_trial, diverged = [], jnp.bool_(False)
        for t, p, jac, g, v in zip(mc.plan.trials, mc.points, jacs, naturals, mc.values):
            stats, div = indirect.binding_draws(mc.plan.layout, t, p, f, keys, IDENTIFY_NUMERICS)
            diverged = diverged | jnp.any(div)
            cov = g @ indirect.covariance(jac, stats, mc.n_draws) @ g.T
            per_trial.append(_criterion_value(cov, v, mc.plan.idx, mc.plan.criterion))
        return _aggregate(per_trial, mc.plan.criterion, mc.plan.aggregate, smooth), diverged

    return jax.jit(jax.value_and_grad(objective, has_aux=True))


class _Adam(NamedTuple):
    """The optimiser's state: ``log(shape)``, Adam's state, the displacement gain, the
    smoothed criterion per step (NaN: skipped) and the steps skipped."""

    log_shape: np.ndarray
    opt_state: optax.OptState
    gain: object
    trace: tuple
    skipped: int


def _adam_init(opt, family, gain) -> _Adam:
    shape0 = np.asarray(family.shape)
    log_shape = np.log(np.maximum(shape0, 1e-6 * shape0.max()))
    return _Adam(log_shape, opt.init(log_shape), gain, (), 0)


def _adam_step(mc: _MonteCarlo, opt, value_and_grad, family, state: _Adam, step: int) -> _Adam:
    """One step on new draws: accepted, or skipped when a draw diverged or the criterion or
    its gradient is not finite (a diverged draw poisons the criterion); the displacement
    gain re-found every ``REGAIN_EVERY`` steps (it scales the whole signal)."""
    keys = jax.random.split(jax.random.fold_in(mc.draw_key, step), mc.n_draws)
    (value, diverged), grad = value_and_grad(state.log_shape, keys, state.gain)
    grad = np.asarray(grad)
    if bool(diverged) or not (np.isfinite(float(value)) and np.all(np.isfinite(grad))):
        state = state._replace(trace=state.trace + (float("nan"),), skipped=state.skipped + 1)
    else:
        state = _adam_accept(opt, state, value, grad)
    if mc.plan.limits.peak_displacement is not None and (step + 1) % REGAIN_EVERY == 0:
        state = state._replace(gain=_gain(mc, replace_unchecked(family, shape=jnp.exp(state.log_shape))))
    return state


def _adam_accept(opt, state: _Adam, value, grad) -> _Adam:
    updates, opt_state = opt.update(grad, state.opt_state, state.log_shape)
    # kept on the host: arrays placed by the sharded step would make the next call recompile
    return state._replace(
        log_shape=np.asarray(state.log_shape + updates),
        opt_state=jax.tree.map(np.asarray, opt_state),
        trace=state.trace + (float(value),),
    )


def design_monte_carlo(plan: DesignPlan, candidates, *, draws: int, predict_draws: int) -> Design:
    """The Monte Carlo design loop (module docstring; ``design`` checks the inputs first)."""
    t_start = time.perf_counter()
    steps, progress = plan.steps, plan.progress
    mc = _monte_carlo(plan, draws, predict_draws)
    family, gain, f0, before, start_criteria = _best_start(mc, candidates)
    value_and_grad = _objective(mc, family, f0)
    opt = plan.optimizer
    state = _adam_init(opt, family, gain)
    state = descend(
        state,
        lambda s, step: _adam_step(mc, opt, value_and_grad, family, s, step),
        steps,
        after=None if progress is None else lambda s, step: progress(step + 1, steps, s.trace[-1]),
    )
    if state.skipped == steps:
        raise RuntimeError(f"design: every step's noise draws diverged ({steps} steps); the trial is unstable")
    designed = replace_unchecked(family, shape=np.exp(state.log_shape))
    return _assemble(mc, family, designed, np.asarray(f0), before, start_criteria, state, t_start)


def _assemble(mc: _MonteCarlo, family, designed, start_signal, before, start_criteria, state: _Adam, t_start):
    """The ``Design``: the designed signal at its re-found gain, both predicted on the same
    draws, and the start kept if the design does not beat it."""
    signal = np.asarray(_limited_signal(designed, mc.family_key, mc.n, mc.plan.limits, mc.period, _gain(mc, designed)))
    before = _predictions(mc, jnp.asarray(start_signal)) if before is None else before
    after = _predictions(mc, jnp.asarray(signal))
    if start_criteria[0] is None:
        start_criteria = [_plain(mc, before)]
    improved = _plain(mc, after) < _plain(mc, before)
    if not improved:  # same draws for both: the start is the better design
        designed, signal, after = family, start_signal, before
    final_rms = np.sqrt(np.mean(signal**2, axis=0))
    achieved = dict(
        rms_force=final_rms.tolist(),
        peak_force=np.max(np.abs(signal), axis=0).tolist(),
        peak_displacement=max(float(_peak_displacement(t, jnp.asarray(signal))[0]) for t in mc.plan.trials),
    )
    return Design(
        family=replace_unchecked(designed, rms=final_rms),
        signal=signal,
        start_family=replace_unchecked(family, rms=np.sqrt(np.mean(start_signal**2, axis=0))),
        start_signal=start_signal,
        before=before,
        after=after,
        criterion_before=_plain(mc, before),
        criterion_after=_plain(mc, after),
        trace=list(state.trace),
        achieved=achieved,
        improved=improved,
        skipped=state.skipped,
        start_criteria=start_criteria,
        time_s=time.perf_counter() - t_start,
        trials=list(mc.plan.trials),
        free=tuple(mc.plan.free),
        targets=tuple(mc.plan.layout.labels()[i] for i in mc.plan.idx),
    )
