"""The loop's noise as innovations: a steady-state Kalman filter of the linearised loop.

The recorded ``y = (x - x0, F_h)`` of a near-linear loop is its deterministic response to the
perturbation plus the response ``v`` to its noise (the person's force, the sensors' noise fed
back through the controller, the encoders' steps). ``v`` is the output of the state space of
``linear.py`` driven by white noise, so the Kalman filter of that state space turns it into
white innovations ``e_t`` of covariance ``Lambda``: a causal, exact whitening of the loop's
coloured noise, with no window and no leakage. On it rest the Cramér-Rao bound (``bound.py``),
``sum_t de_t^T Lambda^-1 de_t`` for the whitened derivatives ``de`` of the deterministic
response, and the efficient statistic of ``identify`` (``auxiliary.py``).

Why not the frequency domain (Whittle, ``sum_k dY_k^H (N S_k)^-1 dY_k``): the person's force
puts ten orders of magnitude between the noise's spectrum at 1 Hz and at 20 Hz, and a record's
DFT leaks the low-frequency noise into the high bins far above ``S_k`` there. On 96 simulated
recordings (IMBIC, paper arm 2) the Whittle estimator spread 3-60 times its own "bound", which
was 5 times below the exact one on the stiffness (docs/identification.md, the bound).

The filter is the steady-state one (the Riccati equation solved by the structured doubling
algorithm, differentiable, a fixed number of doublings), started from the loop at rest: on a
20 s record the time-varying filter from the exact start changed the bound by 0.1%.
Outputs are scaled to about unit noise first (``scale``), because positions [m] and forces
[N] differ by five orders of magnitude.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from .linear import LinearLoop

DOUBLINGS = 64  # each squares the filter's convergence factor: far past round-off for any stable loop
# The noise floor of a reading no sensor beats, added to the direct noise of each output (its
# own reading noise): 1 nm of position, 1 uN of force. Without it a noise-free reading (ideal
# encoders) would make the filter's measurement covariance singular.
READING_FLOOR = (1e-9, 1e-9, 1e-6, 1e-6)


class InnovationsFilter(NamedTuple):
    """The steady-state Kalman filter of a loop's noise (a pytree of arrays).

    ``a`` ``(n, n)``, ``c`` ``(4, n)`` (scaled outputs), ``gain`` ``(n, 4)``, ``cov`` ``(4, 4)``
    the innovations' covariance (scaled units), ``scale`` ``(4,)`` the output scale (m, m, N,
    N): the filter runs on ``y / scale``; ``state_cov`` ``(n, n)`` the one-step prediction's
    error covariance (the Riccati equation's solution)."""

    a: jnp.ndarray
    c: jnp.ndarray
    gain: jnp.ndarray
    cov: jnp.ndarray
    scale: jnp.ndarray
    state_cov: jnp.ndarray


def noise_covariances(loop: LinearLoop):
    """``(Q, R, N)``: covariances of the state noise ``B_w w``, the reading noise ``D_w w`` and
    their cross-covariance, per period, for the white noise inputs ``w`` (``loop.noise_var``)."""
    bw, dw = loop.b[:, 2:], loop.d[:, 2:]
    bs, ds = bw * loop.noise_var[None, :], dw * loop.noise_var[None, :]
    return bs @ bw.T, ds @ dw.T, bs @ dw.T


def _riccati(a, g, h):
    """``X = a^T X (I + g X)^-1 a + h`` by structured doubling (Chu, Fan and Lin 2005)."""
    eye = jnp.eye(a.shape[0], dtype=a.dtype)

    def doubling(_, state):
        ak, gk, hk = state
        w = eye + gk @ hk
        a_w = jnp.linalg.solve(w.T, ak.T).T  # a_k (I + g_k h_k)^-1
        return a_w @ ak, gk + a_w @ gk @ ak.T, hk + ak.T @ hk @ jnp.linalg.solve(w, ak)

    return jax.lax.fori_loop(0, DOUBLINGS, doubling, (a, g, h))[2]


def innovations_filter(loop: LinearLoop) -> InnovationsFilter:
    """The steady-state Kalman filter of ``loop``'s noise (see the module docstring).

    Needs a stable loop (``linear.spectral_radius`` below 1). Traceable and differentiable."""
    q, r, cross = noise_covariances(loop)
    floor = jnp.asarray(READING_FLOOR, dtype=r.dtype)
    scale = jnp.sqrt(jnp.diag(r) + floor * floor)
    c = loop.c / scale[:, None]
    r = r / jnp.outer(scale, scale) + jnp.diag((floor / scale) ** 2)
    cross = cross / scale[None, :]
    r_inv = jnp.linalg.inv(r)
    a_bar = loop.a - cross @ r_inv @ c  # the cross-covariance taken out of the dynamics
    q_bar = q - cross @ r_inv @ cross.T
    p = _riccati(a_bar.T, c.T @ r_inv @ c, 0.5 * (q_bar + q_bar.T))
    p = 0.5 * (p + p.T)
    cov = c @ p @ c.T + r
    gain = (loop.a @ p @ c.T + cross) @ jnp.linalg.inv(cov)
    return InnovationsFilter(loop.a, c, gain, 0.5 * (cov + cov.T), scale, p)


def whiten(filt: InnovationsFilter, z):
    """Innovations ``(N, 4, ...)`` (scaled units) of the signals ``z`` ``(N, 4, ...)`` [m, m, N,
    N]: the filter run from rest over the record. Linear in ``z``; trailing axes are columns."""
    zs = z / filt.scale.reshape((1, 4) + (1,) * (z.ndim - 2))

    def step(state, zt):
        e = zt - filt.c @ state
        return filt.a @ state + filt.gain @ e, e

    start = jnp.zeros((filt.a.shape[0],) + z.shape[2:], dtype=zs.dtype)
    return jax.lax.scan(step, start, zs)[1]


def whiten_transpose(filt: InnovationsFilter, cot):
    """The transpose of ``whiten``: ``G`` ``(N, 4, ...)`` with ``sum_t cot_t . whiten(z)_t =
    sum_t G_t . z_t`` for every ``z`` (a reverse-time scan of the filter's adjoint; ``cot`` in
    the innovations' scaled units, ``G`` per metre and newton)."""
    closed = filt.a - filt.gain @ filt.c

    def step(lam, ct):
        return filt.c.T @ ct + closed.T @ lam, ct - filt.gain.T @ lam

    start = jnp.zeros((filt.a.shape[0],) + cot.shape[2:], dtype=cot.dtype)
    g = jax.lax.scan(step, start, cot, reverse=True)[1]
    return g / filt.scale.reshape((1, 4) + (1,) * (cot.ndim - 2))


def information(filt: InnovationsFilter, dy):
    """Fisher information ``(p, p)`` of ``p`` parameters whose deterministic response has the
    derivatives ``dy`` ``(N, 4, p)`` [m, N per parameter unit]: ``sum_t de_t^T Lambda^-1 de_t``."""
    de = whiten(filt, dy)
    return jnp.einsum("tip,ij,tjq->pq", de, jnp.linalg.inv(filt.cov), de)
