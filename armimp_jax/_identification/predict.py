"""The standard errors an experiment will give, before it is run: ``predict_se``.

The same method as ``identify``'s covariance, in expectation: at the trial's own parameter
values, recordings simulated with the trial's noise model (sensor noise, voluntary force)
are pushed through one Gauss-Newton step of the fit (residuals scaled and, with
``noise_order > 0``, whitened as ``identify`` does); the spread of those steps is the
predicted covariance. Pure JAX from the perturbation on: differentiable in ``f`` (common
random numbers: the draws are fixed by ``key``), so experiment design can optimise it by
gradient.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from .._checks import as_float64, check_int, require_x64
from .._estimation.welch import check_finite
from .._simulate import Trial
from .._solver.numerics import Numerics
from . import layout as lay
from . import model_fit as mf
from .model_fit import IDENTIFY_NUMERICS


class PredictedSE(NamedTuple):
    """``predict_se``'s answer (a pytree of arrays): ``se`` ``{name: array}`` in each parameter's
    units and shape; ``covariance`` ``(n, n)`` of every entry (order of ``labels``);
    ``bias`` ``{name: array}``, the first-order bias the noise gives the estimate; ``labels``."""

    se: dict
    covariance: jnp.ndarray
    bias: dict
    labels: tuple


def _unflatten(layout, flat):
    out, i = {}, 0
    for name in layout.names:
        shape = layout.shape(name)
        n = 1
        for d in shape:
            n *= d
        out[name] = flat[i : i + n].reshape(shape)
        i += n
    return out


def predict_se(
    trial: Trial,
    f,
    *,
    free,
    symmetric=(),
    numerics: Numerics | None = None,
    key=None,
    bootstrap: int = 100,
    noise_order: int = 0,
    band=None,
) -> PredictedSE:
    """Predicted standard errors of ``identify(trial-like model, f, ...)`` for a planned experiment.

    Args:
        trial: the experiment as planned: the true (or assumed) parameter values, and the
            noise it will meet (``Sensors``, ``VoluntaryForce``); its noise must be on.
        f: the perturbation ``F_Delta`` ``(N, 2)`` [N] (may be traced: ``jax.grad`` flows).
        free, symmetric: as ``identify``.
        numerics: as ``identify`` (default ``IDENTIFY_NUMERICS``).
        key: ``jax.random`` key of the noise draws (default ``key(0)``).
        bootstrap: noise draws (>= 10); the SEs carry a Monte Carlo error of about
            ``1 / sqrt(2 bootstrap)``.
        noise_order: as ``identify`` (0: output error).
        band: as ``identify`` (``(low, high)`` [Hz] or ``None``).

    Returns a ``PredictedSE``.
    """
    require_x64("predict_se")
    if not isinstance(trial, Trial):
        raise ValueError(f"predict_se: trial must be a Trial (from make_trial), got {type(trial).__name__}")
    if trial.sensors.ideal and trial.voluntary is None:
        raise ValueError("predict_se: the trial has no noise (ideal sensors, no voluntary force): nothing to predict")
    layout = lay.make_layout(free, symmetric)
    f = as_float64("f", f, where="predict_se")
    if f.ndim != 2 or f.shape[1] != 2:
        raise ValueError(f"predict_se: f must have shape (N, 2), got {f.shape}")
    check_finite("f", f, where="predict_se")
    bootstrap = check_int("bootstrap", bootstrap, minimum=10)
    noise_order = check_int("noise_order", noise_order, minimum=0)
    weights = mf.check_band(band, f.shape[0], "predict_se")
    if weights is not None and noise_order:
        raise ValueError(f"predict_se: pass band or noise_order, not both (got noise_order={noise_order})")
    numerics = IDENTIFY_NUMERICS if numerics is None else numerics
    key = jax.random.key(0) if key is None else key
    p = lay.pack(layout, trial)
    return _predict_se(layout, trial, p, f, jax.random.split(key, bootstrap), numerics, noise_order, weights)


def _predict_se(layout, trial, p, f, keys, numerics, noise_order, band):
    y0 = mf.predict(layout, trial, p, f, numerics)[0]
    ys, _ = mf.noisy_outputs(layout, trial, p, f, keys, numerics)
    scale = jnp.mean(jnp.std(ys, axis=1), axis=0)  # what identify divides a recording by
    noise = mf.fit_noise_model((y0[None] - ys) / scale[None, None, :], noise_order) if noise_order else band
    _, jac = mf.residual_jacobian(layout, trial, p, f, y0, scale, noise, numerics)
    steps = mf.bootstrap_steps(ys, y0, scale, noise, mf.gauss_newton_map(jac))
    g = lay.natural_jacobian(layout, p, trial)
    cov = g @ jnp.cov(steps.T, ddof=1).reshape(p.shape[0], p.shape[0]) @ g.T
    return PredictedSE(
        se=_unflatten(layout, jnp.sqrt(jnp.diag(cov))),
        covariance=cov,
        bias=_unflatten(layout, g @ jnp.mean(steps, axis=0)),
        labels=tuple(layout.labels()),
    )
