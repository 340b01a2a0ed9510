"""The search of ``identify``: Gauss-Newton on the mismatch of statistics, as a small state
(``Search``) and pure steps (``init``, ``step``) over a fixed ``Problem``.

Steps on the weighted mismatch ``b - beta(p)`` (``indirect.py``): the binding's Jacobian ``A``
is reused between them (a chord) and recomputed after a step of more than
``JACOBIAN_REUSE_SE`` standard errors or one that fails; a step is halved while a draw
diverges or the mismatch grows (a stale slope gets two tries before it is refreshed). A step
that moves every parameter by less than ``FINAL_STEP_SE`` of its SE (a barely told nuisance,
below) is taken without halving: without friction it is the last, taken without a binding of
its own (a step from that near lands within a fraction of itself); through friction it is
checked by a binding of its own, and the search goes on.
Where a nuisance the recordings barely tell moves more, the search stops instead when a step
moves every other parameter by less than ``CONVERGED_FRACTION`` of its SE, or by less than
twice the binding's own Monte Carlo error (``1 / sqrt(R)`` SE: a smaller step chases the
draws' noise).

Far from the answer the draws' noise does not matter: the search starts **coarse**, the
binding on ``COARSE_DRAWS`` of the draws and the slope on ``COARSE_JACOBIAN_DRAWS``, and takes
all of them once a step moves every parameter by less than ``FINE_WITHIN_SE`` of its SE (or a
coarse step fails); only a fine step may settle, and the covariance is computed at the answer
with every draw (a coarse slope there is refreshed).

Every parameter but the arm's (the friction's, the robot's and the force channel's
calibration) is a nuisance for the arm: each carries a prior about its start (``PRIOR_SD`` on
its internal scale), one more moment of the match with its own variance in ``Omega``, so one
the recordings cannot tell stays within its range, with an interval as wide as the prior,
and the arm's covariance carries its uncertainty. Why not
optimistix's least-squares solvers: the cost is in Monte Carlo draws and the Jacobian is the
expensive part, so it is reused across steps, and the stopping rule is in standard errors
that the draws at each step give.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .._simulate import Trial
from .._solver.numerics import Numerics
from . import efficient, indirect
from . import layout as lay
from .auxiliary import statistic_labels

CONVERGED_FRACTION = 0.15  # a step below this many SEs: converged (the binding's own MC error is 1/sqrt(R) SE)
NOISE_MULTIPLE = 2.0  # ... or below this many times the binding's own MC error, 1/sqrt(R) SE
COARSE_DRAWS = 8  # the binding's draws far from the answer (rounded up to the devices)
COARSE_JACOBIAN_DRAWS = 2  # the slope's draws far from the answer (rounded up to the devices)
FINE_WITHIN_SE = 2.0  # coarse steps until one moves every parameter by less than this many SEs
JACOBIAN_REUSE_SE = 3.0  # A computed within this many SEs of the estimate serves its covariance
# A fine step that moves every parameter by less than this many SEs (a barely told nuisance by less
# than the settling fraction) is taken whole, without halving (``_final_step``).
FINAL_STEP_SE = 1.0
HALVINGS = 6  # a step is halved at most this many times while a draw diverges or the mismatch grows
# The nuisance prior of each free friction parameter: this SD on its internal (log or logit) scale
# about its start, a factor of e^2 ~ 7 either way.
PRIOR_SD = 2.0
# The stream (``jax.random.fold_in`` of a part's first key) of ``spread_ratio``'s prior draws: far from
# the sample indices the draws' own noise folds in.
SPREAD_STREAM = 2**31 - 1


class Part(NamedTuple):
    """One binding of the problem: its own layout (the free parameters it sees), model,
    perturbation ``f``, keys of its noise draws, arm statistic (``None``: Welch), ``index``,
    the positions in the search's vector ``p`` of its own internal parameters, and ``count``,
    the recordings it serves (repeated trials: their statistics' mean is matched)."""

    layout: lay.Layout
    model: Trial
    f: jnp.ndarray
    keys: jnp.ndarray
    arm_stat: efficient.Efficient | None
    index: np.ndarray
    count: int = 1


class Problem(NamedTuple):
    """What the search holds fixed: the recordings (``parts``), the numerics, the Jacobian's
    draws ``n_jac``, the recordings' statistics ``b`` (one after the other, then the nuisance
    prior's means), the nuisance prior (``prior_index`` into ``p``, ``prior_mean``), the
    mismatch's Monte Carlo slack and the length ``size`` of ``p``. The recordings are
    independent: their statistics' covariance is block-diagonal."""

    parts: tuple
    numerics: Numerics
    n_jac: int
    noisy: bool
    b: np.ndarray
    prior_index: np.ndarray
    prior_mean: np.ndarray
    slack: float
    size: int
    chord: bool = False  # the fine slope is the binding's chord (friction in a noisy loop), not its tangent
    calibration: object = None  # calibration_prior.Calibrated: held in the models, carried into the covariance

    @property
    def n_draws(self) -> int:
        return self.parts[0].keys.shape[0]


class Search(NamedTuple):
    """The search's state: the parameters ``p``, the binding there (``mean``, ``stats``), the
    mismatch ``cost``, the slope ``jac`` (computed at ``jac_at``) and its weights ``w``, the
    SEs of the last step, the steps taken, ``history``, ``problems`` and whether it is done."""

    p: np.ndarray
    mean: np.ndarray
    stats: np.ndarray
    cost: float
    jac: np.ndarray | None
    jac_at: np.ndarray
    w: np.ndarray
    se_p: np.ndarray | None
    iterations: int
    history: tuple
    problems: tuple
    done: bool
    draws: int = 0  # the binding's draws now (the coarse stage's fewer)
    jac_draws: int = 0  # the draws behind ``jac``


def _with_prior(problem: Problem, p, mean, stats, jac=None):
    """The binding's mean, draws and slope with the nuisance prior's moments appended (each
    prior moment is its parameter, with no spread over the draws)."""
    k = problem.prior_index
    mean = np.concatenate([mean, p[k]])
    stats = np.concatenate([stats, np.broadcast_to(p[k], (stats.shape[0], k.size))], axis=1)
    if jac is not None:
        jac = np.concatenate([jac, np.eye(p.size)[k]])
    return mean, stats, jac


def _weights(problem: Problem, stats, jac):
    m = stats.shape[1] - problem.prior_index.size
    w = np.asarray(indirect.weights(stats[:, :m], None if jac is None else jac[:m]))
    return np.concatenate([w, np.full(problem.prior_index.size, PRIOR_SD**-2)])


def _blocks(problem: Problem) -> list[slice]:
    """The rows of each recording's statistics in ``b`` (``auxiliary.statistic_labels``)."""
    out, i = [], 0
    for part in problem.parts:
        n = len(statistic_labels(part.layout))
        out.append(slice(i, i + n))
        i += n
    return out


def _sensitivity(jac, w):
    """``S = H^-1 A^T W`` ``(n, m)``: how the estimate answers the statistics to first order."""
    aw = jac.T * w[None, :]
    return np.linalg.solve(aw @ jac, aw)


def _covariance(problem: Problem, jac, stats, n_draws, w):
    """The sandwich covariance with ``Omega`` block-diagonal: each recording's statistics' own
    covariance over its draws, then the prior's own variance."""
    m = stats.shape[1] - problem.prior_index.size
    omega = np.zeros((stats.shape[1],) * 2)
    if stats.shape[0] > 1:
        # a mean of `count` recordings spreads as one over the count; the binding's own MC error adds 1 / R
        for rows, part in zip(_blocks(problem), problem.parts, strict=True):
            scale = 1.0 / part.count + 1.0 / n_draws
            omega[rows, rows] = scale * np.atleast_2d(np.cov(stats[:, rows].T, ddof=1))
    omega[m:, m:] = PRIOR_SD**2 * np.eye(problem.prior_index.size)
    sens = _sensitivity(jac, w)
    return sens @ omega @ sens.T


def _binding(problem: Problem, p, draws=None):
    parts, diverged = [], False
    for part in problem.parts:
        keys = part.keys if draws is None else part.keys[:draws]
        stats, div = indirect.binding_draws(
            part.layout, part.model, jnp.asarray(p[part.index]), part.f, keys, problem.numerics, part.arm_stat
        )
        parts.append(np.asarray(stats))
        diverged |= bool(np.asarray(div).any())
    stats = np.concatenate(parts, axis=1)
    mean, stats, _ = _with_prior(problem, p, stats.mean(axis=0), stats)
    return mean, stats, diverged


def _jacobian(problem: Problem, p, draws=None):
    blocks, draws = [], problem.n_jac if draws is None else draws
    for part in problem.parts:
        jac, div = indirect.binding_jacobian(
            part.layout,
            part.model,
            jnp.asarray(p[part.index]),
            part.f,
            part.keys[: problem.n_jac],
            problem.numerics,
            part.arm_stat,
            count=draws,
        )
        jac = np.asarray(jac)
        if bool(div) or not np.all(np.isfinite(jac)):
            return None
        full = np.zeros((jac.shape[0], problem.size))
        full[:, part.index] = jac
        blocks.append(full)
    return _with_prior(problem, p, np.zeros(0), np.zeros((1, 0)), np.concatenate(blocks, axis=0))[2]


def _slope(problem: Problem, p, se_p):
    """The fine stage's slope: the binding's chord over +-1 SE (``indirect.chord``, on
    ``indirect.CHORD_DRAWS`` of the draws) where the problem asks for it and the SEs give its
    widths, else (and for a column whose draws diverge) the tangent on every Jacobian draw."""
    if not (problem.chord and se_p is not None and np.all(np.isfinite(se_p)) and np.all(se_p > 0)):
        return _jacobian(problem, p)
    return indirect.chord(_chord_binding(problem, p), p, np.asarray(se_p, dtype=float), lambda: _jacobian(problem, p))


def _chord_binding(problem: Problem, p):
    """``means_at(points (k, n)) -> (means, diverged)``: ``_binding`` on ``indirect.CHORD_DRAWS``
    of the draws at each point, each part simulating only the points that move its parameters
    from ``p`` (a chord column moves one parameter: pooled recordings then cost the parts that
    hold it, not all of them), in batched calls (``indirect.binding_means``). A part a point
    leaves at ``p`` gives zeros: a chord column differences two such points, whose bindings
    there are the same (and sound: ``p``'s binding was checked on these draws)."""
    draws = indirect.chord_draws(problem.n_draws)

    def means_at(points):
        blocks, diverged = [], np.zeros(points.shape[0], dtype=bool)
        for part in problem.parts:
            subs = points[:, part.index]
            moved = np.any(subs != p[part.index][None, :], axis=1)
            means = np.zeros((points.shape[0], len(statistic_labels(part.layout))))
            if np.any(moved):
                means[moved], div = indirect.binding_means(
                    part.layout, part.model, subs[moved], part.f, part.keys[:draws], problem.numerics, part.arm_stat
                )
                diverged[moved] |= div
            blocks.append(means)
        return np.concatenate([*blocks, points[:, problem.prior_index]], axis=1), diverged

    return means_at


def _cost(problem: Problem, mean, w):
    d = problem.b - mean
    return 0.5 * float(d @ (w * d))


def _coarse_counts(problem: Problem) -> tuple[int, int]:
    """``(draws, jacobian draws)`` of the coarse stage: fewer than the problem's, as multiples of
    the local devices (the problem's own where it has no more)."""
    n_dev = jax.local_device_count()

    def rounded(n):
        return int(math.ceil(n / n_dev) * n_dev)

    draws = min(problem.n_draws, rounded(COARSE_DRAWS)) if problem.noisy else problem.n_draws
    return draws, min(problem.n_jac, rounded(COARSE_JACOBIAN_DRAWS)) if problem.noisy else problem.n_jac


def init(problem: Problem, p0) -> Search:
    draws, jac_draws = _coarse_counts(problem)
    mean, stats, diverged = _binding(problem, p0, draws)
    if diverged:
        raise ValueError("identify: noisy simulations of the model diverge at the start; choose another start")
    jac = _jacobian(problem, p0, jac_draws)
    w = _weights(problem, stats, jac)
    problems = () if jac is not None else ("the binding's Jacobian is not finite at the start",)
    cost = _cost(problem, mean, w)
    return Search(p0, mean, stats, cost, jac, p0, w, None, 0, (), problems, jac is None, draws, jac_draws)


def _fine(problem: Problem, state: Search) -> Search:
    """The search at the same ``p`` with every draw, and the slope on every Jacobian draw: the
    fine steps are chords on it, and the covariance takes it where the answer is near."""
    mean, stats, diverged = _binding(problem, state.p)
    if diverged:
        why = "recordings simulated at the search's first answer went unstable"
        return state._replace(problems=state.problems + (why,), done=True)
    fine_slope = problem.chord or state.jac_draws < problem.n_jac
    jac = _slope(problem, state.p, state.se_p) if fine_slope else None
    if jac is not None:
        state = state._replace(jac=jac, jac_at=state.p, jac_draws=problem.n_jac)
    w = _weights(problem, stats, state.jac)
    return state._replace(mean=mean, stats=stats, w=w, cost=_cost(problem, mean, w), draws=problem.n_draws)


def _propose(problem: Problem, state: Search, step):
    """The largest of ``step``, ``step / 2``, ... whose simulations are sound and whose
    mismatch is no worse (a stale slope gets two tries before it is refreshed):
    ``(kept, p, mean, stats, cost, scale)``."""
    stale = not np.array_equal(state.jac_at, state.p)
    scale = 1.0
    slack = problem.slack * problem.n_draws / state.draws  # the mismatch's MC jitter at the draws in use
    for _ in range(2 if stale else HALVINGS + 1):
        trial_p = state.p + scale * step
        mean, stats, diverged = _binding(problem, trial_p, state.draws)
        cost = _cost(problem, mean, state.w) if np.all(np.isfinite(mean)) else math.inf
        if not diverged and cost < state.cost + slack:
            return True, trial_p, mean, stats, cost, scale
        scale *= 0.5
    return False, state.p, state.mean, state.stats, state.cost, scale


def step(problem: Problem, state: Search, max_steps: int) -> Search:
    """One Gauss-Newton step of the search (see the module docstring)."""
    jac, w = state.jac, state.w
    step = np.asarray(indirect.gauss_newton_step(jac, w, problem.b - state.mean))
    if not np.all(np.isfinite(step)):
        why = "some free parameter does not change what the recording shows (the search's slope is singular)"
        return state._replace(problems=state.problems + (why,), done=True)
    se_p = np.sqrt(np.diag(_covariance(problem, jac, state.stats, state.draws, w)))
    # settled: every parameter moves by less than a fraction of its SE, but a nuisance the
    # recording barely tells (its SE most of its prior's), which may wander inside its prior
    told = np.ones(step.size, dtype=bool)
    told[problem.prior_index] = se_p[problem.prior_index] <= 0.5 * PRIOR_SD
    step_se = float(np.max(np.abs(step[told]) / se_p[told])) if problem.noisy else math.nan
    coarse = state.draws < problem.n_draws
    history = state.history + (dict(cost=state.cost, step_se=step_se, draws=state.draws),)
    state = state._replace(se_p=se_p, history=history)
    if coarse and step_se <= FINE_WITHIN_SE:
        return _fine(problem, state)
    settle = max(CONVERGED_FRACTION, NOISE_MULTIPLE / math.sqrt(problem.n_draws))
    # a barely told nuisance's SE is most of its prior's: it takes no unchecked step of more than `settle`
    near = np.where(told, FINAL_STEP_SE, settle) * se_p
    last = problem.noisy and not coarse and np.all(np.abs(step) <= near)
    if last and not problem.chord:  # the last step, taken on the linear prediction
        return _final_step(problem, state, step)
    if problem.noisy and not coarse and np.all(np.abs(step[told]) <= settle * se_p[told]):
        return state._replace(done=True)
    if not problem.noisy and np.all(np.abs(step) <= 1e-10 * (1.0 + np.abs(state.p))):
        return state._replace(done=True)  # noise-free: converged to round-off
    if state.iterations == max_steps:
        return state._replace(problems=state.problems + (f"the search did not settle in {max_steps} steps",), done=True)
    if last:  # through friction: checked by a binding, and the search goes on
        return _final_step(problem, state, step)
    stale = not np.array_equal(state.jac_at, state.p)
    kept, p, mean, stats, cost, scale = _propose(problem, state, step)
    if kept:
        state = state._replace(p=p, mean=mean, stats=stats, cost=cost, iterations=state.iterations + 1)
    else:
        state = state._replace(history=history[:-1] + (dict(history[-1], refused=True),))
    if kept and np.all(np.abs(scale * step) <= JACOBIAN_REUSE_SE * se_p):
        return state
    jac_draws = problem.n_jac if not coarse else state.jac_draws
    new = None
    if stale or kept:
        new = _jacobian(problem, state.p, jac_draws) if coarse else _slope(problem, state.p, state.se_p)
    if new is None:
        if kept:
            return state
        if coarse:  # a coarse step that fails: go on with every draw
            return _fine(problem, state)
        why = (
            f"the search stalled after {state.iterations} steps: no step from there lowered the mismatch between "
            "the recording and the model while keeping its simulations stable"
        )
        return state._replace(problems=state.problems + (why,), done=True)
    w = _weights(problem, state.stats, new)
    return state._replace(jac=new, jac_at=state.p, w=w, cost=_cost(problem, state.mean, w), jac_draws=jac_draws)


def _final_step(problem: Problem, state: Search, step) -> Search:
    """A step from within ``FINAL_STEP_SE`` of the answer.

    Without friction the binding is near linear and its slope the tangent's, so a step from that
    near lands within a fraction of itself: it is taken without a binding of its own (the
    mismatch the linear prediction's) and ends the search. Through friction the linear
    prediction is not the mismatch (a slope taken where the binding bends, or a parameter whose
    SE is large where the search stands, can promise a root that is not there): the step is
    checked by a binding of its own and the search goes on from the new point, ending when a step
    there moves every told parameter by less than the settling fraction of its SE. A step whose
    simulations diverge is not taken: the search then ends where it stands, unsettled."""
    p = state.p + step
    if not problem.chord:
        mean = state.mean + state.jac @ step
        cost = _cost(problem, mean, state.w)
        return state._replace(p=p, mean=mean, cost=cost, iterations=state.iterations + 1, done=True)
    mean, stats, diverged = _binding(problem, p)
    if diverged or not np.all(np.isfinite(mean)):
        why = "recordings simulated one step from the answer went unstable"
        return state._replace(problems=state.problems + (why,), done=True)
    w = _weights(problem, stats, state.jac)
    cost = _cost(problem, mean, w)
    return state._replace(p=p, mean=mean, stats=stats, w=w, cost=cost, iterations=state.iterations + 1)


class Final(NamedTuple):
    """The answer's covariance and what it rests on (``final_covariance``): ``cov`` of ``p``,
    the search's ``problems``, ``check`` (``spread_ratio``'s answer, or ``None``) and ``sens``,
    the answer's first-order sensitivity to the statistics ``S = H^-1 A^T W`` (``None`` without
    a slope or noise)."""

    cov: np.ndarray
    problems: tuple
    check: tuple | None
    sens: np.ndarray | None = None


def final_covariance(problem: Problem, state: Search) -> Final:
    """The covariance of ``p`` at the estimate (the slope refreshed if it is far from there), with
    the search's problems. Where the slope is a chord (friction in a noisy loop), ``check`` is
    ``spread_ratio``'s answer and each parameter's SD is widened by its ratio where that is above
    1 (never narrowed: the ratio's own noise then errs wide). Measured on
    docs/identification.md section 6b's cells, the widened intervals hold entry by entry where
    the linearised ones did not (the stiffness through 1 N m at arm 4)."""
    jac, problems = state.jac, state.problems
    n_draws = problem.n_draws
    if jac is not None and state.se_p is not None:
        far = not np.all(np.abs(state.p - state.jac_at) <= JACOBIAN_REUSE_SE * state.se_p)
        if far or state.jac_draws < problem.n_jac:  # a slope far from the answer, or a coarse one
            jac = _slope(problem, state.p, state.se_p)
            if jac is None:
                problems = problems + ("the binding's Jacobian is not finite at the estimate",)
    if jac is None:
        return Final(np.full((state.p.size,) * 2, np.nan), problems, None)
    if not problem.noisy:
        return Final(np.zeros((state.p.size,) * 2), problems, None)
    w = _weights(problem, state.stats, jac)
    cov = _covariance(problem, jac, state.stats, n_draws, w)
    sens = _sensitivity(jac, w)
    if not problem.chord:
        return Final(cov, problems, None, sens)
    check = spread_ratio(problem, state.p, state.stats, jac, w)
    if check[0] is not None:  # each SE widened to its re-estimates' spread, the correlations kept
        widen = np.maximum(1.0, check[0])
        cov = cov * widen[:, None] * widen[None, :]
    return Final(cov, problems, check, sens)


def spread_ratio(problem: Problem, p, stats, jac, w) -> tuple[np.ndarray | None, int, int]:
    """``(ratio (n,) | None, dropped, count)``: how far the estimate's spread departs from its
    linearisation, per parameter (internal scale), from ``count`` re-estimates, ``dropped`` of
    them left out for a diverged simulation (``None`` with fewer than 3 sound).

    Re-estimates from recordings simulated near the estimate (``stats``: the last binding's
    draws beyond the chord's, ``indirect.chord_draws``; a part matching the mean of ``count``
    repeated recordings takes its draws' deviations over ``sqrt(count)``): each first by the
    linearisation, ``lin = p + S (s - b)`` (``S = H^-1 A^T W``, the covariance's), then one
    Gauss-Newton step more on the binding there (the chord's draws: common random numbers, so
    the binding's own Monte Carlo error shifts every re-estimate alike). The ratio of their SDs
    is 1 where the binding is straight over the estimate's spread and its slope is ``A``'s;
    above 1 where it bends (second order), or where its slope at ``p`` is steeper or flatter
    than the chord's, taken up to ``JACOBIAN_REUSE_SE`` away (first order: the estimate then
    answers a new recording by ``(S A_p)^-1 S``, which the step's ``2 - S A_p`` follows to first
    order). Either way the intervals, which are ``S``'s, hold less often than they say. The
    statistics' draws may be the last step's, not ``p``'s (``_final_step``): that shifts every
    re-estimate alike. The nuisance prior's moment is drawn about its value with the prior's SD
    (as ``Omega`` takes it), on a stream of its own."""
    chord = indirect.chord_draws(problem.n_draws)
    count = min(indirect.CHORD_BATCH // chord, stats.shape[0] - chord)  # one batched call of the chord's
    if count < 3:
        return None, 0, max(count, 0)
    m = stats.shape[1] - problem.prior_index.size
    sens = _sensitivity(jac, w)
    base = stats[:chord].mean(axis=0)
    s = stats[chord : chord + count].copy()
    for rows, part in zip(_blocks(problem), problem.parts, strict=True):
        s[:, rows] = base[rows] + (s[:, rows] - base[rows]) / math.sqrt(part.count)
    key = jax.random.fold_in(problem.parts[0].keys[0], SPREAD_STREAM)
    s[:, m:] = base[m:] + PRIOR_SD * np.asarray(jax.random.normal(key, (count, problem.prior_index.size)))
    lin = p[None, :] + (s - base[None, :]) @ sens.T
    means, diverged = _chord_binding(problem, p)(lin)  # every lin moves every part's parameters
    full = lin + (s - means) @ sens.T
    ok = ~np.asarray(diverged) & np.all(np.isfinite(full), axis=1)
    if ok.sum() < 3:
        return None, int(count - ok.sum()), count
    spread = np.std(lin[ok], axis=0, ddof=1)
    return np.std(full[ok], axis=0, ddof=1) / np.where(spread > 0, spread, np.inf), int(count - ok.sum()), count
