"""The arm's efficient statistic: a one-step generalised least-squares fit of the linearised loop.

``identify`` matches statistics of the recording through the simulation (``indirect.py``).
The classical Welch fit (``auxiliary.arm_statistics``) sees the arm only through the ratio of
two spectra at 1 Hz bins, which throws away what the loop's own dynamics tell: how the
known perturbation moves the hand through the (known) robot, at every frequency. This
statistic keeps it. About a reference ``p_ref`` of the arm's parameters:

    s(y) = p_ref + H^-1 sum_t de_t^T W e_t,    e = whiten(y - y_ref),  de = whiten(d y_ref / dp),

one Gauss-Newton step of the Gaussian likelihood of the frictionless loop linearised about rest
(``linear.py``), its coloured noise whitened by the loop's Kalman filter (``kalman.py``),
``H = sum_t de_t^T W de_t``. Near a linear loop and a reference within a few standard errors,
its variance is the Cramér-Rao bound: the statistic is efficient, and indirect inference
keeps it so (the binding is then near the identity), while the simulation corrects what
the linear model leaves out (friction, the robot's nonlinear kinematics, sampling).

``W`` is ``Lambda^-1``, the innovations' inverse covariance; where the trial has friction,
whose effect on the loop is no part of the linear model, the innovations of recordings
simulated with it are not white, and ``W`` becomes a frequency-dependent ``4 x 4`` weight,
the inverse of their spectral matrix estimated from simulated draws (``excess_weight``;
after the whitening its dynamic range is small, so a Welch estimate is sound).

The statistic is linear in the recording, so it is stored as ``s(y) = p_ref + sum_t
weights_t . (y_t - y_ref,t)`` (``Efficient``): a simulated recording costs one contraction.
``fit_linear`` finds the reference from the recording itself (Gauss-Newton on the same
likelihood), so the statistic is centred where the data put the arm.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from . import kalman, linear
from . import layout as lay

SPECTRUM_NPERSEG = 1024  # Welch segments of the innovations' excess spectrum (~1 Hz bins at 1 kHz)
FIT_STEPS = 30  # Gauss-Newton steps of fit_linear at most
# fit_linear stops when a step moves every parameter by less than this many SEs: the centre of the
# statistic need only be near (indirect inference corrects the rest), and Gauss-Newton on this
# cost converges linearly, so a tight tolerance costs many steps (docs/performance.md, "The binding's draws")
FIT_TOLERANCE = 0.2
HALVINGS = 8
# Eigenvalues of the unit-diagonal information below this fraction of the largest are directions
# a recording does not tell (pseudo-inverse, where the calibration is free).
CONFOUNDED_RTOL = 1e-8


class Efficient(NamedTuple):
    """The efficient statistic of a reference (a pytree of arrays): ``s(y) = ref + sum_t
    weights_t . (y_t - y_ref,t)``; ``ref`` ``(n,)`` the arm's internal parameters,
    ``y_ref`` ``(N, 4)`` the linear loop's response there (``x - x0`` [m], ``F_h`` [N]),
    ``weights`` ``(N, 4, n)``, ``information`` ``(n, n)`` (``H``, of the linear model)."""

    ref: jnp.ndarray
    y_ref: jnp.ndarray
    weights: jnp.ndarray
    information: jnp.ndarray


def recorded(trial, x, fh):
    """``y`` ``(N, 4)``: a recording as the statistic reads it, ``x - x0`` [m] then ``F_h`` [N]."""
    return jnp.concatenate([x - trial.x0[None, :], fh], axis=1)


def apply(stat: Efficient, trial, x, fh):
    """The statistic ``(n,)`` of a recording ``x`` [m], ``fh`` [N] ``(N, 2)`` each."""
    return stat.ref + jnp.einsum("tin,ti->n", stat.weights, recorded(trial, x, fh) - stat.y_ref)


def _spectra(a):
    """DFT of ``a`` ``(N, 4, ...)`` at the bins ``1 .. N/2 - 1``."""
    return jnp.fft.rfft(a, axis=0)[1 : a.shape[0] // 2]


def _gram(filt, a, b, weight):
    """``(p, q)`` products of whitened signals ``a`` ``(N, 4, p)`` and ``b`` ``(N, 4, q)``:
    ``sum_t a_t^T Lambda^-1 b_t`` when ``weight`` is ``None``, else ``sum_k 2 Re[A_k^H W_k B_k] / N``
    over the DFT bins ``1 .. N/2 - 1`` (``W_k = weight[k - 1]``; with ``W_k = Lambda^-1`` the two
    agree but for the DC and Nyquist bins)."""
    if weight is None:
        return jnp.einsum("tip,ij,tjq->pq", a, jnp.linalg.inv(filt.cov), b)
    product = jnp.einsum("kip,kij,kjq->pq", jnp.conj(_spectra(a)), weight, _spectra(b))
    return 2.0 * jnp.real(product) / a.shape[0]


def _cotangent(filt, de, weight):
    """``c`` ``(N, 4, p)`` with ``_gram(de, e) = sum_t c_t^T e_t`` for every whitened ``e``: the
    score as a time-domain weighting of the innovations."""
    if weight is None:
        return jnp.einsum("ij,tjp->tip", jnp.linalg.inv(filt.cov), de)
    n = de.shape[0]
    q = jnp.einsum("kij,kjp->kip", weight, _spectra(de))
    full = jnp.zeros((n,) + q.shape[1:], dtype=q.dtype).at[1 : n // 2].set(q)
    # sum_k 2 Re[Q_k^H E_k] / N = sum_t (2 Re[ifft(Q)_t]) . e_t
    return 2.0 * jnp.real(jnp.fft.ifft(full, axis=0))


@functools.partial(jax.jit, static_argnames="layout")
def efficient_statistic(layout: lay.Layout, trial, p_ref, f, weight=None) -> Efficient:
    """The statistic about ``p_ref`` (``layout``: arm matrices only) for the perturbation ``f``
    ``(N, 2)`` [N]; ``weight`` ``(N/2 - 1, 4, 4)`` the innovations' inverse spectral matrix
    per bin, or ``None`` (``Lambda^-1``, the frictionless loop's own)."""
    y_ref, dy = _response(layout, trial, p_ref, f)
    filt = kalman.innovations_filter(linear.linearise(lay.with_values(layout, trial, p_ref)))
    de = kalman.whiten(filt, dy)
    h = _gram(filt, de, de, weight)
    gamma = kalman.whiten_transpose(filt, _cotangent(filt, de, weight))  # (N, 4, n): the score's weights
    return Efficient(p_ref, y_ref, jnp.einsum("tjn,nm->tjm", gamma, _inverse(layout, h)), h)


def _confounded(layout) -> bool:
    """Whether the layout frees the robot's or the force channel's calibration, which one
    recording may not tell apart from the arm (the robot's inertia and the arm's mass add)."""
    return any(n not in lay.ARM_PARAMETERS for n in layout.names)


def _inverse(layout, h):
    """``H^-1``; where the calibration is free, the pseudo-inverse of ``H`` scaled to a unit
    diagonal: directions one recording cannot tell apart leave its statistic where it is (the
    other recordings of a pooled identification tell them)."""
    if not _confounded(layout):
        return jnp.linalg.inv(h)
    d = 1.0 / jnp.sqrt(jnp.diag(h))
    return d[:, None] * jnp.linalg.pinv(d[:, None] * h * d[None, :], rtol=CONFOUNDED_RTOL) * d[None, :]


def _response(layout, trial, p, f):
    def response(q):
        return linear.respond(linear.linearise(lay.with_values(layout, trial, q)), f)

    return response(p), jax.jacfwd(response)(p)


@functools.partial(jax.jit, static_argnames="layout")
def _fit_step(layout, trial, p, f, y, filt, weight):
    """Gauss-Newton step on the weighted whitened residual's cost (``_gram(e, e)``, ``e =
    whiten(y - y_lin(p))``, the filter and weight held), the cost before it and the step's SEs."""
    y_lin, dy = _response(layout, trial, p, f)
    e, de = kalman.whiten(filt, y - y_lin)[:, :, None], kalman.whiten(filt, dy)
    h = _gram(filt, de, de, weight)
    h_inv = _inverse(layout, h)
    step = (
        h_inv @ _gram(filt, de, e, weight)[:, 0]
        if _confounded(layout)
        else jnp.linalg.solve(h, _gram(filt, de, e, weight)[:, 0])
    )
    return step, _gram(filt, e, e, weight)[0, 0], jnp.sqrt(jnp.diag(h_inv))


@functools.partial(jax.jit, static_argnames="layout")
def _cost(layout, trial, p, f, y, filt, weight):
    e = kalman.whiten(filt, y - linear.respond(linear.linearise(lay.with_values(layout, trial, p)), f))[:, :, None]
    return _gram(filt, e, e, weight)[0, 0]


@functools.partial(jax.jit, static_argnames="layout")
def filter_at(layout, trial, p):
    """The loop's innovations filter with the arm at ``p`` (``layout``: arm matrices)."""
    return kalman.innovations_filter(linear.linearise(lay.with_values(layout, trial, p)))


def _descend(layout, trial, p, f, y, filt, weight):
    """Gauss-Newton with step halving on the whitened residual's cost under a held filter;
    ``(p, converged)``."""
    for _ in range(FIT_STEPS):
        step, cost, se = (np.asarray(v) for v in _fit_step(layout, trial, jnp.asarray(p), f, y, filt, weight))
        if not np.all(np.isfinite(step)):
            return p, False
        if np.all(np.abs(step) <= FIT_TOLERANCE * se):
            return p, True
        for _ in range(HALVINGS):
            new = float(_cost(layout, trial, jnp.asarray(p + step), f, y, filt, weight))
            if np.isfinite(new) and new <= cost:
                p = p + step
                break
            step = 0.5 * step
        else:
            return p, False
    return p, False


def fit_linear(layout: lay.Layout, trial, p0, f, y, weight=None):
    """The arm's parameters ``(n,)`` that best explain the recording ``y`` ``(N, 4)`` (``x - x0``,
    ``F_h``) through the frictionless linearised loop, from ``p0``: Gauss-Newton on the
    whitened residual (weighted by ``weight`` as ``efficient_statistic``), first with the
    noise's filter of ``p0``, then with that of the answer (the noise model moves with the
    arm). Returns ``(p, converged)``."""
    p = np.asarray(p0, dtype=float)
    converged = False
    for _ in range(2):
        p, converged = _descend(layout, trial, p, f, y, filter_at(layout, trial, jnp.asarray(p)), weight)
        if not converged:
            break
    return p, converged


def excess_weight(filt, ys):
    """The innovations' inverse spectral matrix ``(N/2 - 1, 4, 4)`` at the bins of an ``N``-sample
    record, from simulated recordings ``ys`` ``(R, N, 4)`` (``x - x0``, ``F_h``): their
    innovations less the draws' mean, Welch (``SPECTRUM_NPERSEG``-sample Hann segments,
    averaged over segments and draws), each bin given its nearest Welch bin's value. Pure JAX."""
    n = ys.shape[1]
    nperseg = int(min(SPECTRUM_NPERSEG, 2 ** int(np.floor(np.log2(max(n // 4, 64))))))
    residuals = jax.vmap(lambda y: kalman.whiten(filt, y))(ys - jnp.mean(ys, axis=0, keepdims=True))
    _, spec = jax.scipy.signal.csd(
        residuals[..., :, None], residuals[..., None, :], nperseg=nperseg, axis=-3, detrend=False
    )
    spec = jnp.mean(spec, axis=0)  # over draws: (F, 4, 4)
    spec = 0.5 * (spec + jnp.conj(jnp.swapaxes(spec, -1, -2)))
    nearest = np.clip(np.rint(np.arange(1, n // 2) / n * nperseg).astype(int), 1, spec.shape[0] - 1)
    return jnp.linalg.inv(spec[nearest])
