"""The pieces of model-based identification that ``identify`` and ``predict_se`` share: the
predictor (the noise-free closed-loop simulation), the weighted output residual and its
exact Jacobian, the Levenberg-Marquardt solve, and the linearised parametric bootstrap.

Residual of a recording ``y = (x, F_h)`` ``(N, 4)`` at parameters ``p`` (``layout.py``):
``r(p) = (y_sim(p) - y) / s``, flattened, with ``s`` ``(4,)`` one scale per channel
(position and force axes; fixed during a fit). ``y_sim`` is the trial simulated with
ideal sensors and no voluntary force: the model's prediction given the commanded
``F_Delta`` alone (output error).

Linearised bootstrap. Near the estimate, one Gauss-Newton step ``-A r`` with ``A = (J^T
J)^-1 J^T`` maps a recording's residual to the estimate's change. Recordings simulated
from the fitted model *with* its noise (sensor noise and voluntary force, the trial's
noise model) give residuals ``r_b`` that are coloured, fed back through the controller,
and shaped by the friction state along the input: ``-A r_b`` spreads as the estimate
does, without assuming any of that away. Their covariance is the reported covariance;
their mean is the estimator's first-order bias.

Noise model (prediction error). With the person's force and sensor noise fed back through
the loop, the output residual is strongly coloured (most of it below a few hertz) and
correlated across the four channels. A vector autoregression of order ``q`` fitted to the
residuals, ``e_t = sum_k A_k e_t-k + v_t`` with innovations ``v_t`` of covariance ``S``,
gives the whitening filter ``w_t = S^-1/2 (e_t - sum_k A_k e_t-k)`` (zero history before
the record); fitting ``p`` to the whitened residual is the prediction-error method with
that noise model held fixed.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import optimistix as optx

from .._model.sensors import IDEAL
from .._pytree import replace_unchecked
from .._simulate import Trial, simulate
from .._solver.graded import GradedARK4
from .._solver.numerics import Numerics
from .layout import Layout, with_values

# The converged step at every friction in [0, 4] N m and the cheapest measured (docs/performance.md).
IDENTIFY_NUMERICS = Numerics(solver=GradedARK4(), substeps=4)
BOOTSTRAP_BATCH = 32  # noisy re-simulations per vmapped batch (memory: ~2 MB each per 20 s)


def quiet(trial: Trial) -> Trial:
    """The predictor's trial: ideal sensors, no voluntary force (the model without noise)."""
    return replace_unchecked(trial, sensors=IDEAL, voluntary=None)


def outputs(sim) -> jnp.ndarray:
    """The recorded channels ``(N, 4)``: ``x`` [m] then ``F_h`` [N]."""
    return jnp.concatenate([sim.x, sim.fh], axis=1)


def predict(layout: Layout, model: Trial, p, f, numerics):
    """``(y_sim (N, 4), diverged)`` of the noise-free model at ``p``."""
    sim = simulate(with_values(layout, quiet(model), p), f, numerics=numerics)
    return outputs(sim), sim.diverged


def value_and_jacobian(fun, p):
    """``fun(p)`` and its Jacobian ``(P, *out)`` by one vmapped forward pass (the primal runs
    once: it does not depend on the tangent)."""

    def tangent(t):
        return jax.jvp(fun, (p,), (t,))

    y, dy = jax.vmap(tangent)(jnp.eye(p.shape[0], dtype=p.dtype))
    return y[0], dy


class NoiseModel(NamedTuple):
    """A VAR whitening filter: ``coef`` ``(4 q, 4)`` (lags 1..q stacked) and ``whiten`` ``(4, 4)``,
    the inverse Cholesky factor of the innovations' covariance. ``None`` stands for output
    error (no filter)."""

    coef: jnp.ndarray
    whiten: jnp.ndarray


class Band(NamedTuple):
    """A frequency weighting of the residual: ``weights`` ``(N // 2 + 1,)`` on its real FFT's
    bins (1 inside the band, raised-cosine edges, 0 outside). The cost is then the
    residual's energy in the band (Parseval): the person's slow force and the sensors'
    broadband noise outside it carry no weight."""

    weights: jnp.ndarray


def band_weights(n: int, low: float, high: float, *, rate: float = 1000.0, edge: float = 1.0) -> Band:
    """``Band`` of an ``n``-sample residual at ``rate`` [Hz] passing ``[low, high]`` [Hz], with
    raised-cosine edges ``edge`` [Hz] wide outside the band (``low = 0``: no lower edge)."""
    freq = jnp.fft.rfftfreq(n, 1.0 / rate)

    def rise(d):  # 0 at d = -edge, 1 at d = 0
        return jnp.where(d >= 0, 1.0, jnp.where(d <= -edge, 0.0, 0.5 * (1 + jnp.cos(jnp.pi * d / edge))))

    w = rise(high - freq) * (1.0 if low <= 0 else rise(freq - low))
    return Band(w)


def check_band(band, n: int, where: str):
    """``None``, or the ``Band`` of an ``n``-sample record for ``band = (low, high)`` [Hz];
    one-line errors for a band outside ``[0, 500)`` Hz or narrower than the record resolves."""
    if band is None:
        return None
    try:
        low, high = (float(b) for b in band)
    except (TypeError, ValueError):
        raise ValueError(f"{where}: band must be (low, high) in Hz, got {band!r}") from None
    resolution = 1000.0 / n
    if not (0.0 <= low and low + 2 * resolution < high < 500.0):
        raise ValueError(
            f"{where}: band must satisfy 0 <= low < high < 500 Hz with high - low > {2 * resolution:.3g} Hz "
            f"(two bins of a {n}-sample record), got {band!r}"
        )
    return band_weights(n, low, high)


def _lagged(e, order: int):
    """``(N, 4 q)``: row ``t`` holds ``e_t-1 .. e_t-q`` (zeros before the record)."""
    n = e.shape[0]
    padded = jnp.concatenate([jnp.zeros((order,) + e.shape[1:], e.dtype), e], axis=0)
    return jnp.concatenate([padded[order - k - 1 : order - k - 1 + n] for k in range(order)], axis=1)


def fit_noise_model(e, order: int) -> NoiseModel:
    """Least-squares VAR(``order``) of residuals ``e`` ``(N, 4)`` (or ``(B, N, 4)``, pooled)."""
    e = e.reshape((-1,) + e.shape[-2:])
    x = jax.vmap(lambda a: _lagged(a, order)[order:])(e).reshape(-1, 4 * order)
    t = e[:, order:].reshape(-1, e.shape[-1])
    coef = jnp.linalg.lstsq(x, t)[0]
    innov = t - x @ coef
    cov = innov.T @ innov / innov.shape[0]
    return NoiseModel(coef, jnp.linalg.inv(jnp.linalg.cholesky(cov)))


def apply_noise_model(noise: NoiseModel | None, e):
    """Whitened residual ``(N, 4)`` of ``e`` ``(N, 4)`` (``e`` itself under output error)."""
    if noise is None:
        return e
    if isinstance(noise, Band):
        return jnp.fft.irfft(jnp.fft.rfft(e, axis=0) * noise.weights[:, None], n=e.shape[0], axis=0)
    n, c = e.shape
    order = noise.coef.shape[0] // c
    padded = jnp.concatenate([jnp.zeros((order, c), e.dtype), e], axis=0)
    # lag by lag: the stacked (N, 4 q) regressor would be large under the Jacobian's vmap
    predicted = sum(padded[order - k - 1 : order - k - 1 + n] @ noise.coef[k * c : (k + 1) * c] for k in range(order))
    return (e - predicted) @ noise.whiten.T


def residual(layout, model, p, f, y, scale, noise, numerics):
    """The (whitened) residual ``(4N,)`` of the recording ``y`` at ``p``: ``(y_sim(p) - y) / scale``."""
    y_sim = predict(layout, model, p, f, numerics)[0]
    return apply_noise_model(noise, (y_sim - y) / scale[None, :]).reshape(-1)


def residual_jacobian(layout: Layout, model: Trial, p, f, y, scale, noise, numerics):
    """Residual ``r`` ``(4N,)`` and its Jacobian ``J = dr/dp`` ``(4N, P)`` at ``p``."""
    r, jac = value_and_jacobian(lambda q: residual(layout, model, q, f, y, scale, noise, numerics), p)
    return r, jac.T


def levenberg_marquardt(layout, model, p0, colscale, f, y, scale, noise, numerics, max_steps: int, tol: float):
    """Minimise ``|r(p)|^2 / 2`` from ``p0`` with optimistix's Levenberg-Marquardt, on
    ``theta = (p - p0) / colscale``. Returns ``(p, successful, steps)``. Pure: jit and vmap it.

    Each evaluation computes the residual and its Jacobian in one vmapped forward pass (a
    custom JVP hands the solver the matrix instead of a linearised simulation it would
    re-run once per column)."""

    def res_of_theta(theta):
        return residual(layout, model, p0 + theta * colscale, f, y, scale, noise, numerics)

    @jax.custom_jvp
    def res(theta):
        return res_of_theta(theta)

    @res.defjvp
    def _res_jvp(primals, tangents):
        r, jac = value_and_jacobian(res_of_theta, primals[0])
        return r, jnp.tensordot(tangents[0], jac, axes=1)

    solver = optx.LevenbergMarquardt(rtol=tol, atol=tol)
    sol = optx.least_squares(lambda theta, _: res(theta), solver, jnp.zeros_like(p0), max_steps=max_steps, throw=False)
    ok = sol.result == optx.RESULTS.successful
    return p0 + sol.value * colscale, ok, sol.stats["num_steps"]


def gauss_newton_map(jac):
    """``A = (J^T J)^-1 J^T`` ``(P, 4N)`` by QR (one GN step is ``-A r``)."""
    q, rr = jnp.linalg.qr(jac)
    return jax.scipy.linalg.solve_triangular(rr, q.T, lower=False)


def noisy_outputs(layout, model: Trial, p, f, keys, numerics):
    """Recordings ``(B, N, 4)`` re-simulated at ``p`` with the trial's noise (sensors and
    voluntary force), one per key (``keys`` ``(B,)``), and whether any diverged."""
    noisy = with_values(layout, model, p)

    def one(key):
        sim = simulate(noisy, f, key=key, numerics=numerics)
        return outputs(sim), sim.diverged

    ys, diverged = jax.lax.map(one, keys, batch_size=BOOTSTRAP_BATCH)
    return ys, jnp.any(diverged)


def bootstrap_steps(ys, y_fit, scale, noise, gn_map):
    """``-A r_b`` ``(B, P)``: one Gauss-Newton step from the fit per re-simulated recording
    ``ys`` ``(B, N, 4)`` (``y_fit`` ``(N, 4)`` the noise-free prediction there)."""
    return jax.vmap(lambda yb: -(gn_map @ apply_noise_model(noise, (y_fit - yb) / scale[None, :]).reshape(-1)))(ys)
