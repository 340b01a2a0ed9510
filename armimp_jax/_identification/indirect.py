"""Indirect inference through the closed loop: the binding function, its Jacobian, and the
covariance they give.

A recording's statistics ``b = s(y)`` (``auxiliary.py``, ``m`` of them) are matched by the
model's: the **binding** ``beta(p) = mean_r s(y_r(p))`` over ``R`` recordings simulated at
the internal parameters ``p`` (``layout.py``, ``n <= m`` of them) with the trial's own noise
(sensor noise, encoder steps, the person's force), each from a fixed key (common random
numbers: ``beta`` is a smooth, deterministic function of ``p``). The estimate minimises
``(b - beta(p))^T W (b - beta(p))`` with ``W = diag(1 / var s)`` (each statistic in units of
its own spread over the draws; with ``m = n`` it solves ``beta(p) = b``). Near the solution
``b - beta(p) ~ A (p_true - p) + noise`` with ``A = d beta / dp``, so

    cov(p_hat) = (1 + 1/R) H^-1 A^T W Omega W A H^-1,   H = A^T W A,

``Omega`` the statistics' covariance over the draws at ``p_hat`` and the ``1/R`` the
binding's own Monte Carlo error (Gourieroux, Monfort and Renault 1993; with ``m = n``,
``A^-1 Omega A^-T``). Everything the noise does in the loop (coloured, fed back, modulated
by the friction) is in ``Omega``, and the statistics' bias (Welch, sampling, friction) is
in ``beta``: the intervals need only that ``beta`` be near linear over a few standard
errors, which statistics close to the parameters make it (docs/identification.md). A
diagonal ``W`` rather than ``Omega^-1``: the inverse of a covariance estimated from ``R``
draws is biased by ``R / (R - m - 2)`` and would make the intervals too narrow.

Draws are spread over the local devices (``shard_map`` over ``_batch.make_mesh(jax.local_devices())``):
``R`` must be a multiple of their number.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import PartitionSpec as P

from .._batch import make_mesh
from .._model.sensors import quiet
from .._pytree import replace_unchecked
from .._simulate import Trial, simulate
from .._solver.graded import GradedARK4
from .._solver.numerics import Numerics
from . import efficient
from .auxiliary import statistic_labels, statistics
from .layout import LINEAR, Layout, with_values

# The converged step at every friction in [0, 4] N m and the cheapest measured (docs/performance.md).
IDENTIFY_NUMERICS = Numerics(solver=GradedARK4(), substeps=4)
# Draws behind the efficient statistic's weight under friction (efficient.excess_weight): each Welch
# bin then averages some 600 segments, a few percent of scatter in the weight.
WEIGHT_DRAWS = 16
# The draws behind the binding's chord through friction (``chord``; ``search._slope``): their SEs
# against 64 draws' are measured in docs/identification.md section 6b.
CHORD_DRAWS = 8
# Simulations in one call of the chord's bindings (``binding_means``): wider batches run each
# simulation faster on XLA:CPU up to about this width, then slower (docs/performance.md, "The binding's draws").
CHORD_BATCH = 112


def arm_layout(layout: Layout) -> Layout | None:
    """The layout of ``layout``'s parameters of the linearised loop alone: the arm's matrices and
    the robot's and force channel's calibration (``None`` when none is free)."""
    return layout.linear()


def arm_index(layout: Layout) -> np.ndarray:
    """Positions of those parameters' internal entries in ``p``."""
    return layout.index(LINEAR)


def weight_draws(n_draws: int) -> int:
    """Draws behind the efficient statistic's weight: ``WEIGHT_DRAWS``, a multiple of the local
    devices, at most ``n_draws``."""
    n_dev = jax.local_device_count()
    return int(min(n_draws, math.ceil(WEIGHT_DRAWS / n_dev) * n_dev))


@functools.partial(jax.jit, static_argnames=("layout", "numerics"))
def statistic_weight(layout: Layout, model: Trial, p, f, keys, numerics):
    """The efficient statistic's weight under friction (``efficient.excess_weight``) from
    recordings simulated at ``p`` with ``keys``. Its own program, run to the end before the
    binding's: inside one program with the sharded draws it hung (XLA:CPU collectives)."""
    arm, idx = arm_layout(layout), arm_index(layout)
    ys, _ = draw_recordings(layout, model, p, f, keys, numerics)
    return efficient.excess_weight(efficient.filter_at(arm, model, p[idx]), ys)


def arm_statistic(layout: Layout, model: Trial, p, f, weight=None):
    """The efficient statistic (``efficient.py``) about the arm's entries of ``p`` (``weight``:
    ``statistic_weight``'s, under friction)."""
    arm, idx = arm_layout(layout), arm_index(layout)
    return efficient.efficient_statistic(arm, model, p[idx], f, weight)


def predict(layout: Layout, model: Trial, p, f, numerics):
    """``(y (N, 4), diverged)``: the model at ``p`` without noise (``sensors.quiet``: a force from
    the motor torques stays one; no voluntary force), its recorded ``x`` [m] then ``F_h`` [N]."""
    noiseless = replace_unchecked(with_values(layout, model, p), sensors=quiet(model.sensors), voluntary=None)
    sim = simulate(noiseless, f, numerics=numerics)
    return jnp.concatenate([sim.x, sim.fh], axis=1), sim.diverged


def draw_counts(model: Trial, draws: int, jacobian_draws: int) -> tuple[int, int]:
    """The draws actually used: rounded up to a multiple of the local devices (they are split
    over them); one of each for a model without noise (every draw would be the same)."""
    if not model.noisy:
        draws, jacobian_draws = 1, 1
    n_dev = jax.local_device_count()
    return tuple(int(math.ceil(d / n_dev) * n_dev) for d in (draws, jacobian_draws))


def draw_statistics(layout: Layout, model: Trial, p, f, key, numerics, arm_stat=None, stat_layout=None):
    """The statistics of one noisy recording at ``p`` and whether it diverged (``arm_stat``: the
    arm's statistic, ``auxiliary.statistics``; ``stat_layout``: the parameters the statistics are
    of, default ``layout``'s: a larger ``layout`` gives their slope in parameters held fixed)."""
    trial = with_values(layout, model, p)
    sim = simulate(trial, f, key=key, numerics=numerics)
    return statistics(stat_layout or layout, trial, f, sim.x, sim.fh, arm_stat), sim.diverged


def draw_recordings(layout: Layout, model: Trial, p, f, keys, numerics):
    """``(y (R, N, 4), diverged (R,))``: noisy recordings at ``p`` (``x - x0`` [m], ``F_h`` [N]),
    vmapped on one device: they feed a reduction over the draws, and a program that split them
    over the CPU devices and then reduced across them hung at that collective (XLA:CPU)."""

    def one(k):
        trial = with_values(layout, model, p)
        sim = simulate(trial, f, key=k, numerics=numerics)
        return jnp.concatenate([sim.x - trial.x0[None, :], sim.fh], axis=1), sim.diverged

    return jax.vmap(one)(keys)


def _sharded(fn, n_out: int, n_in: int = 1):
    """``fn(*inputs)`` run with its ``n_in`` inputs split along their first axis over the local
    devices; its ``n_out`` outputs concatenated."""
    spec = P("batch")
    return jax.shard_map(
        fn, mesh=make_mesh(jax.local_devices()), in_specs=(spec,) * n_in, out_specs=(spec,) * n_out, check_vma=False
    )


@functools.partial(jax.jit, static_argnames=("layout", "numerics", "stat_layout"))
def binding_draws(layout: Layout, model: Trial, p, f, keys, numerics, arm_stat=None, stat_layout=None):
    """``(stats (R, n), diverged (R,))``: the statistics of ``R`` noisy recordings at ``p``
    (one per key), vmapped on each device (``stat_layout``: as ``draw_statistics``)."""

    def per_device(k):
        return jax.vmap(lambda kk: draw_statistics(layout, model, p, f, kk, numerics, arm_stat, stat_layout))(k)

    return _sharded(per_device, 2)(keys)


@functools.partial(jax.jit, static_argnames=("layout", "numerics", "stat_layout"))
def binding_jacobian(layout: Layout, model: Trial, p, f, keys, numerics, arm_stat=None, stat_layout=None, count=None):
    """``A = d beta / d p`` ``(m, n)`` averaged over the draws of ``keys`` (forward mode: one
    pass per draw carries every parameter's tangent), and whether a draw diverged
    (``stat_layout``: as ``draw_statistics``). ``count`` (traced; default every key): the draws
    used, a multiple of the local devices, each device taking the first ``count / devices`` of
    its share of ``keys``: one program serves the search's coarse slope and its fine one."""
    n_dev = jax.local_device_count()
    count = keys.shape[0] if count is None else count
    per_count = jnp.asarray(count, dtype=jnp.int32) // n_dev

    def one(k):
        def stats(q):
            return draw_statistics(layout, model, q, f, k, numerics, arm_stat, stat_layout)

        return jax.jacfwd(stats, has_aux=True)(p)

    def per_device(k):
        # one draw at a time (a vmap over draws of the tangents' batch ran several times slower),
        # as many as asked: a loop of traced length
        def body(i, acc):
            jac, div = one(k[i])
            return acc[0] + jac, acc[1] | div

        # the slope's shape from the layout: tracing `one` for it would double the trace time
        zero = (jnp.zeros((len(statistic_labels(stat_layout or layout)), p.shape[0]), p.dtype), jnp.zeros((), bool))
        total, diverged = jax.lax.fori_loop(0, per_count, body, zero)
        return total[None], diverged[None]

    totals, diverged = _sharded(per_device, 2)(keys)
    return jnp.sum(totals, axis=0) / (per_count * n_dev), jnp.any(diverged)


@functools.partial(jax.jit, static_argnames=("layout", "numerics", "stat_layout"))
def binding_draws_at(layout: Layout, model: Trial, points, f, keys, numerics, arm_stat=None, stat_layout=None):
    """``(stats (k R, n), diverged (k R,))``: ``binding_draws`` at each of ``k`` points ``(k, n)``
    with the same ``R`` keys (common random numbers), point-major, in one program: the chord's
    bindings batched (``binding_means``)."""
    k, r = points.shape[0], keys.shape[0]
    pair = jnp.arange(k * r)
    pts, ks = points[pair // r], keys[pair % r]

    def per_device(q, kk):
        return jax.vmap(lambda qq, key: draw_statistics(layout, model, qq, f, key, numerics, arm_stat, stat_layout))(
            q, kk
        )

    return _sharded(per_device, 2, n_in=2)(pts, ks)


def _bucket(k: int, cap: int) -> int:
    """Points in the next call: the power of two at or above ``k``, at most ``cap`` (few shapes,
    few programs to compile)."""
    return min(cap, 1 << max(0, (k - 1).bit_length()))


def binding_means(layout: Layout, model: Trial, points, f, keys, numerics, arm_stat=None, stat_layout=None):
    """``(means (k, n), diverged (k,))`` on the host: the binding at each of ``points`` ``(k, n)``
    averaged over the draws of ``keys``, and whether any of its draws diverged. Run in calls of
    ``CHORD_BATCH`` simulations (a short last call padded with its last point)."""
    points = np.atleast_2d(np.asarray(points, dtype=float))
    if points.shape[0] == 0:
        raise ValueError("binding_means: no points given")
    r = keys.shape[0]
    cap = max(1, CHORD_BATCH // r)
    means, diverged, i = [], [], 0
    while i < points.shape[0]:
        size = _bucket(points.shape[0] - i, cap)
        chunk = points[i : i + size]
        pad = np.concatenate([chunk, np.repeat(chunk[-1:], size - chunk.shape[0], axis=0)])
        stats, div = binding_draws_at(layout, model, jnp.asarray(pad), f, keys, numerics, arm_stat, stat_layout)
        means.append(np.asarray(stats).reshape(size, r, -1)[: chunk.shape[0]].mean(axis=1))
        diverged.append(np.asarray(div).reshape(size, r)[: chunk.shape[0]].any(axis=1))
        i += chunk.shape[0]
    return np.concatenate(means), np.concatenate(diverged)


def chord_draws(n_draws: int) -> int:
    """The draws behind a chord: ``CHORD_DRAWS``, a multiple of the local devices, at most ``n_draws``."""
    n_dev = jax.local_device_count()
    return int(min(n_draws, math.ceil(CHORD_DRAWS / n_dev) * n_dev))


def chord(means_at, p, half, tangent=None, tries: int = 2) -> np.ndarray | None:
    """``(m, n)``: the binding's slope as central differences, column ``j`` over ``p +- half[j]``
    (``means_at(points (k, n)) -> (means (k, m), diverged (k,))``, on fixed draws: common random
    numbers; every column's two points in one call).

    Why not the tangent (``binding_jacobian``) alone: through friction the binding is a smooth
    chord over its SEs, but each draw's tangent follows where the sticking falls, and the draws'
    mean tangent missed the chord along the stiffness (issue 50, measured in
    docs/identification.md section 6b). The estimate spreads over its SEs, so the chord over them is
    the slope its covariance needs. A column whose draws diverge is tried at half the width,
    ``tries`` times in all; then it is ``tangent``'s (an array, or a function giving it, called
    once; ``None`` if it gives ``None``)."""
    p = np.asarray(p, dtype=float)
    width, cols = np.asarray(half, dtype=float).copy(), [None] * p.size
    todo = list(range(p.size))
    for _ in range(tries):
        if not todo:
            break
        moves = np.zeros((len(todo), p.size))
        moves[np.arange(len(todo)), todo] = width[todo]
        means, diverged = means_at(np.concatenate([p + moves, p - moves]))
        means, diverged = np.asarray(means), np.asarray(diverged)
        for i, j in enumerate(todo):
            col = (means[i] - means[len(todo) + i]) / (2.0 * width[j])
            if not (diverged[i] or diverged[len(todo) + i]) and np.all(np.isfinite(col)):
                cols[j] = col
        todo = [j for j in todo if cols[j] is None]
        width[todo] *= 0.5
    rows = means.shape[1]
    out = np.stack([np.zeros(rows) if c is None else c for c in cols], axis=1)
    if todo:
        fill = tangent() if callable(tangent) else tangent
        if fill is None:
            return None
        out[:, todo] = np.asarray(fill)[:, todo]
    return out


def weights(stats, jac=None):
    """``W`` ``(m,)``: the inverse variance of each statistic over the draws ``(R, m)``; without
    noise (every draw the same), the inverse squared norm of its row of ``A`` ``(m, n)``: each
    statistic then counts by how much it moves with the parameters, whatever its units."""
    var = jnp.var(stats, axis=0, ddof=1)
    if jac is not None and not bool(jnp.any(var > 0)):
        var = jnp.sum(jac * jac, axis=1)
    return jnp.where(var > 0, 1.0 / jnp.where(var > 0, var, 1.0), 1.0)


def gauss_newton_step(jac, w, d):
    """``H^-1 A^T W d``: the step that best removes the mismatch ``d = b - beta(p)``."""
    aw = jac.T * w[None, :]
    return jnp.linalg.solve(aw @ jac, aw @ d)


def covariance(jac, stats, n_draws: int, w=None):
    """``(1 + 1/R) H^-1 A^T W Omega W A H^-1`` from ``A`` ``(m, n)`` and the draws' statistics
    ``(R, m)`` (``W`` from them unless given). NumPy or JAX arrays; differentiable."""
    w = weights(stats) if w is None else w
    omega = jnp.atleast_2d(jnp.cov(stats.T, ddof=1))
    aw = jac.T * w[None, :]
    sens = jnp.linalg.solve(aw @ jac, aw)  # H^-1 A^T W, (n, m)
    return (1.0 + 1.0 / n_draws) * sens @ omega @ sens.T
