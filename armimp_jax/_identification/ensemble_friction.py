"""The model route over an ensemble through friction: indirect inference over simulated ensembles.

Through Coulomb friction the noise-free simulation is not the mean of the noisy loop, so the
frictionless route's fit of each reach's deviation (``ensemble_identify``) walks off the truth.
As the still ``identify`` does (``indirect.py``), this route matches **statistics** of the lab's
ensemble with their mean over ensembles simulated through the friction, with the lab's own
perturbations and the trial's noise, from fixed keys (common random numbers):

- the arm's: one generalised least-squares step of the *frictionless* loop linearised along the
  path at the classical answer ``p0`` (its Jacobians and Kalman filter held there), a linear map
  of the data, ``s = p0 + H0^-1 sum_r J_r^T W y_r``: one entry per knot entry, near the identity
  in the arm's parameters;
- the friction's: per joint, the still route's regression of the joint torques on the motion
  (``auxiliary.friction_statistics``, the controller replayed along the planned path), averaged
  over the reaches.

Both are means over reaches of per-reach contributions ``c_r``, and the reaches are independent,
so their covariance is ``Omega = sum_r cov(c_r) / R^2``, each reach's spread taken across the
simulated ensembles (which share the lab's perturbations): ``DRAWS`` ensembles give
``R (DRAWS - 1)`` degrees of freedom, not ``DRAWS``. The slope ``A = d beta / d p`` is the
binding's one-sided chord (one SE per column, on ``CHORD_DRAWS`` ensembles), as through friction
in the still route: tangents through stick-slip mislead. The chord is noisy where the arm rests
(before and after the reach the joints stick, and a knot's stiffness there moves the sticking
chaotically: measured, the columns of the first and last knots' ``K`` carry most of its noise), so
the search's own slope is the chord corrected along every step it takes (Broyden's update, on
every draw), and the covariance takes it too. The friction's parameters carry the
still route's nuisance prior (``search.PRIOR_SD`` on their internal scale about the start), so
one the reaches cannot tell (``tau_c`` under IMBIC) stays in its range and the arm's intervals
carry its share. The estimate solves ``A^T W (b - beta(p)) = prior`` by Gauss-Newton; its
covariance is the sandwich ``(1 + 1/DRAWS) S Omega S^T``.

The route assumes what the simulated ensembles assume: the person's planned path is the model's
(through friction the whole motion matters, not only the deviations from the mean path).
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .._simulate import Trial
from . import layout as lay
from . import path as ph
from . import path_bound as pb
from .auxiliary import friction_statistics
from .linear import without_friction
from .search import PRIOR_SD, _sensitivity

DRAWS = 8  # simulated ensembles behind the binding and Omega
CHORD_DRAWS = 4  # simulated ensembles behind each column of the chord (the first of the binding's keys)
BATCH = 2  # ensembles per compiled call (one program for every binding and chord point)
CONVERGED_SE = 0.15  # a step below this many SEs in every parameter ends the search
# The mismatch a step may add before it is halved: the binding's own jitter between nearby points
# (the draws' stick-slip and encoder steps move with p), a fraction of the cost's ~m.
SLACK = 2.0
HALVINGS = 4
# The default draws' stream (``fold_in`` of ``key(0)``): ``simulate_ensemble(key=key(0))`` draws its
# noise from ``fold_in(split(key(0))[1], r)``, which the draws' ``split(fold_in(key(0), 1), R)[r]``
# would repeat exactly (seen: the lab's ensemble among the simulated ones).
DRAW_STREAM = 2**31 - 2


class Statistic(NamedTuple):
    """The arm's statistic, fixed at the start: ``p0``, ``h_inv`` ``(n, n)``, the frictionless loop's
    filter along the path, its noise-free responses ``mu0`` ``(R, N, 4)`` and whitened Jacobians
    less their ensemble mean ``wj`` ``(R, N, 4, n)``."""

    p0: jnp.ndarray
    h_inv: jnp.ndarray
    filt: ph.PathFilter
    mu0: jnp.ndarray
    wj: jnp.ndarray


class Route(NamedTuple):
    """What the search holds fixed: the layouts (arm knots, friction), the model, the
    perturbations ``f`` ``(R, N, 2)``, the statistic, the noise keys ``(DRAWS, R)`` and numerics."""

    knots: ph.KnotLayout
    friction: lay.Layout
    model: Trial
    f: jnp.ndarray
    stat: Statistic
    keys: jnp.ndarray
    numerics: object


def make_statistic(knots, model: Trial, p0, f, numerics) -> Statistic:
    """The arm's statistic at ``p0`` on the model without its Coulomb friction (``path.linearised_at``)."""
    linear = without_friction(model)  # its viscous friction kept: the loop's linear part
    filt, mu, jac = ph.linearised_at(knots, linear, jnp.asarray(p0), f, numerics)
    wj = ph.whiten_centred(filt, jac)
    h_inv = pb.whitened_inverse(wj, knots.labels(), "identify")
    return Statistic(jnp.asarray(p0), jnp.asarray(h_inv), filt, mu, wj)


def contributions(stat: Statistic, model: Trial, f, y):
    """``(c (R, m), energy)``: each reach's share ``c_r`` of the statistics (their mean over reaches,
    plus ``p0`` on the arm's entries), and the whitened deviations' energy about the ensemble's
    mean (the noise check). ``y`` ``(R, N, 4)``: ``x - x0`` and ``F_h``."""
    r = y.shape[0]
    w = jax.vmap(lambda z: ph.whiten(stat.filt, z))(y - stat.mu0)
    arm = r * jnp.einsum("rkip,rki->rp", stat.wj, w) @ stat.h_inv.T
    x = y[..., :2] + model.x0[None, None, :]
    fric = jax.vmap(lambda fr, xr, fhr: friction_statistics(model, fr, xr, fhr).reshape(-1))(f, x, y[..., 2:])
    energy = jnp.sum((w - jnp.mean(w, axis=0, keepdims=True)) ** 2)
    return jnp.concatenate([arm, fric], axis=1), energy


observed = jax.jit(contributions)


def statistic_of(route: Route, contrib) -> np.ndarray:
    """The statistics of one ensemble from its contributions ``(R, m)``."""
    out = np.asarray(contrib).mean(axis=0)
    out[: route.knots.size()] += np.asarray(route.stat.p0)
    return out


def with_parameters(knots: ph.KnotLayout, friction: lay.Layout, model: Trial, p) -> Trial:
    """The model at ``p`` (the arm's knot entries, then the friction's internal values)."""
    n = knots.size()
    return lay.with_values(friction, ph.with_values(knots, model, p[:n]), p[n:])


@functools.partial(jax.jit, static_argnames=("knots", "friction", "numerics"))
def _ensembles(knots, friction, model, stat, p, f, keys, numerics):
    """``(contributions (B, R, m), energies (B,), diverged (B, R))`` of ``B`` ensembles simulated at ``p``."""
    trial = with_parameters(knots, friction, model, p)

    def ensembles(ks):  # whole ensembles on each device: their statistics reduce over its reaches
        b, r = ks.shape[:2]
        fs = jnp.broadcast_to(f, (b, *f.shape)).reshape(-1, *f.shape[1:])
        y, div = ph.recordings(trial, fs, ks.reshape(-1, *ks.shape[2:]), numerics)  # typed or raw keys
        y = y.reshape(b, r, *y.shape[1:])
        contrib, energy = jax.vmap(lambda yy: contributions(stat, model, f, yy))(y)
        return contrib, energy, div.reshape(b, r)

    return ph.split_over_devices(ensembles, keys)


def simulated(route: Route, p, draws: int):
    """``(contributions (draws, R, m), energies (draws,), diverged)`` at ``p`` on the first ``draws`` keys."""
    out, energies, div = [], [], False
    for i in range(0, draws, BATCH):
        (keys,), b = ph.padded_for_devices(route.keys[i : i + BATCH])
        args = (route.knots, route.friction, route.model, route.stat, jnp.asarray(p), route.f, keys, route.numerics)
        c, e, d = ph.on_host(_ensembles(*args), b)
        out.append(c)
        energies.append(e)
        div |= bool(d.any())
    return np.concatenate(out)[:draws], np.concatenate(energies)[:draws], div


def omega(contrib) -> np.ndarray:
    """``(m, m)``: one ensemble's statistics' covariance, from each reach's spread across the
    simulated ensembles (the reaches are independent: ``sum_r cov(c_r) / R^2``)."""
    d, r = contrib.shape[:2]
    dev = contrib - contrib.mean(axis=0, keepdims=True)
    return np.einsum("drp,drq->pq", dev, dev) / ((d - 1) * r * r)


def binding(route: Route, p, draws: int = DRAWS):
    """``(mean statistics (m,), contributions, mean energy, diverged)`` at ``p``."""
    contrib, energy, div = simulated(route, p, draws)
    means = np.stack([statistic_of(route, c) for c in contrib])
    return means.mean(axis=0), contrib, float(energy.mean()), div


def chord(route: Route, p, h, base) -> np.ndarray | None:
    """``(m, n)``: the binding's one-sided chord, column ``j`` over ``h_j`` on ``CHORD_DRAWS``
    ensembles (``base``: the binding there on the same keys); ``None`` where a point diverges."""
    cols = []
    for j in range(p.size):
        q = p.copy()
        q[j] += h[j]
        mean, _, _, div = binding(route, q, CHORD_DRAWS)
        if div:
            return None
        cols.append((mean - base) / h[j])
    return np.stack(cols, axis=1)


def _prior(route: Route, p, prior_mean):
    """The nuisance prior's rows: residuals ``(k,)``, slope ``(k, n)`` and weights ``(k,)`` (each prior
    moment is its parameter, weighted by ``PRIOR_SD^-2``)."""
    n, k = route.knots.size(), prior_mean.size
    slope = np.zeros((k, p.size))
    slope[:, n:] = np.eye(k)
    return prior_mean - p[n:], slope, np.full(k, PRIOR_SD**-2)


def _step(route: Route, p, b, mean, a, w, prior_mean):
    """The Gauss-Newton step on the weighted mismatch with the prior's rows appended, and its
    normal matrix."""
    rp, ap, wp = _prior(route, p, prior_mean)
    res, jac, wt = np.concatenate([b - mean, rp]), np.concatenate([a, ap]), np.concatenate([w, wp])
    h = jac.T @ (wt[:, None] * jac)
    return np.linalg.solve(h, jac.T @ (wt * res)), h


def _cost(route: Route, p, b, mean, w, prior_mean) -> float:
    """The weighted mismatch, the prior's rows included."""
    rp, _, wp = _prior(route, p, prior_mean)
    d = b - mean
    return float(d @ (w * d) + rp @ (wp * rp))


class Answer(NamedTuple):
    """The search's answer: ``p`` (internal scale), its covariance (NaN unless converged), the steps,
    whether it converged and why not, and the noise check's ratio."""

    p: np.ndarray
    covariance: np.ndarray  # internal scale
    steps: int
    converged: bool
    message: str
    noise_ratio: float


def search(route: Route, p0, b, observed_energy, max_steps: int) -> Answer:
    """Gauss-Newton from ``p0`` (module docstring) on the chord corrected along each step (Broyden).
    A step that moves every parameter by less than ``CONVERGED_SE`` of its SE is the last, taken
    whole; a longer one is halved while a draw diverges or the mismatch grows beyond ``SLACK``."""
    n_arm = route.knots.size()
    p, prior_mean = np.asarray(p0, dtype=float).copy(), np.asarray(p0[n_arm:], dtype=float)
    mean, contrib, energy, div = binding(route, p)
    if div:
        return _failed(p, 0, "the reaches simulated at the start diverge: check the model, or give start=")
    w = 1.0 / np.diag(omega(contrib))
    slope = chord(route, p, _h0(route, p), _chord_base(route, contrib))
    if slope is None:
        return _failed(p, 0, "reaches simulated one SE from the start diverge: check the model, or give start=")
    cost = _cost(route, p, b, mean, w, prior_mean)
    for steps in range(1, max_steps + 1):
        step, h = _step(route, p, b, mean, slope, w, prior_mean)
        se = np.sqrt(np.diag(np.linalg.inv(h)))
        last = bool(np.max(np.abs(step) / se) < CONVERGED_SE)
        scale = 1.0
        for _ in range(HALVINGS + 1):
            new_mean, new_contrib, new_energy, div = binding(route, p + scale * step)
            new_cost = _cost(route, p + scale * step, b, new_mean, w, prior_mean)
            if not div and (last or new_cost <= cost + SLACK):
                break
            scale /= 2
        else:
            why = "a draw diverges along the step" if div else "no step lowered the mismatch"
            return _failed(p, steps, f"{why}: start nearer (start=) or record more reaches")
        slope = _broyden(slope, scale * step, new_mean - mean, se)
        p, mean, contrib, energy, cost = p + scale * step, new_mean, new_contrib, new_energy, new_cost
        if last:
            cov = _covariance(route, p, slope, w, contrib, prior_mean)
            return Answer(p, cov, steps, True, "", observed_energy / energy)
    return _failed(p, max_steps, f"no convergence in {max_steps} steps")


def _broyden(slope, step, change, se):
    """``slope`` corrected to map ``step`` to the binding's ``change`` (the least change in the metric of
    the SEs): the chord's noise along the search's own directions gives way to the binding's
    (every draw, where the chord has ``CHORD_DRAWS``), so the steps contract."""
    u = step / se**2
    return slope + np.outer(change - slope @ step, u) / (step @ u)


def _failed(p, steps, message) -> Answer:
    return Answer(p, np.full((p.size, p.size), np.nan), steps, False, message, float("nan"))


def _chord_base(route: Route, contrib) -> np.ndarray:
    return np.stack([statistic_of(route, c) for c in contrib[:CHORD_DRAWS]]).mean(axis=0)


def _h0(route: Route, p) -> np.ndarray:
    """The chord's widths at the start: the arm's SEs on the linear bound, 0.1 on the friction's scale."""
    se_arm = np.sqrt(np.diag(np.asarray(route.stat.h_inv)))
    return np.concatenate([se_arm, np.full(p.size - se_arm.size, 0.1)])


def _covariance(route: Route, p, a, w, contrib, prior_mean) -> np.ndarray:
    """``(1 + 1/DRAWS) S Omega S^T`` with the prior's variance in ``Omega``'s last block, ``S`` on the
    search's own slope (the chord corrected along its steps: a chord's noise alone would inflate
    ``A^T W A`` and narrow the intervals)."""
    rp, ap, wp = _prior(route, p, prior_mean)
    sens = _sensitivity(np.concatenate([a, ap]), np.concatenate([w, wp]))
    m = a.shape[0]
    om = np.zeros((m + rp.size,) * 2)
    om[:m, :m] = (1.0 + 1.0 / contrib.shape[0]) * omega(contrib)
    om[m:, m:] = PRIOR_SD**2 * np.eye(rp.size)
    return sens @ om @ sens.T
