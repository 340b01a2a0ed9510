"""The standard errors an experiment will give, before it is run: ``predict_se``.

``identify``'s covariance, at the planned experiment's own parameter values: the statistics
of recordings simulated with the trial's noise (``Omega``, their covariance over the draws)
and the binding's Jacobian ``A`` give ``indirect.covariance`` (``(1 + 1/R) A^-1 Omega
A^-T`` when there are as many statistics as parameters). Pure
JAX from the perturbation on, with the draws fixed by ``key`` (common random numbers), so
experiment design can optimise it by gradient (through ``Omega`` and ``A`` both). Through
friction, for a concrete perturbation, ``A`` is ``identify``'s: the binding's chord over its
SEs (``indirect.chord``); under tracing it is the tangent, whose gradient design follows.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .._checks import as_float64, check_choice, check_int, is_concrete, require_x64
from .._estimation.welch import check_finite
from .._simulate import Trial
from .._solver.numerics import Numerics
from . import calibration_prior, indirect
from . import layout as lay
from .auxiliary import check_statistic_record
from .bound import has_friction, is_near_linear
from .indirect import IDENTIFY_NUMERICS

STATISTICS = ("auto", "efficient", "welch")


def check_signal(trial: Trial, f, where: str):
    """``f`` as float64 ``(N, 2)`` [N], finite, and long enough for the Welch statistic
    (``check_statistic_record``): one-line errors naming ``where``."""
    f = as_float64("f", f, where=where)
    if f.ndim != 2 or f.shape[1] != 2:
        raise ValueError(f"{where}: f must have shape (N, 2), got {f.shape}")
    check_finite("f", f, where=where)
    check_statistic_record(f.shape[0], trial.period, where)
    return f


def check_sampling(where: str, statistic, numerics, draws, jacobian_draws):
    """``(numerics, draws, jacobian_draws)`` checked, the numerics defaulted to
    ``IDENTIFY_NUMERICS``: the options ``identify`` and ``predict_se`` share, with one-line errors."""
    check_choice("statistic", statistic, STATISTICS)
    draws = check_int("draws", draws, minimum=8)
    jacobian_draws = check_int("jacobian_draws", jacobian_draws, minimum=1)
    if jacobian_draws > draws:  # the Jacobian's draws are the first of the statistics' draws
        raise ValueError(f"{where}: jacobian_draws {jacobian_draws} must be at most draws {draws}")
    numerics = IDENTIFY_NUMERICS if numerics is None else numerics
    if not isinstance(numerics, Numerics):
        raise ValueError(f"{where}: numerics must be a Numerics, got {type(numerics).__name__}")
    return numerics, draws, jacobian_draws


class PredictedSE(NamedTuple):
    """``predict_se``'s answer (a pytree of arrays): ``se`` ``{name: array}`` in each parameter's
    units and shape; ``covariance`` ``(n, n)`` of every entry (order of ``labels``); ``labels``;
    ``diverged``: whether a simulated draw diverged (the prediction is then unsound)."""

    se: dict
    covariance: jnp.ndarray
    labels: tuple
    diverged: jnp.ndarray


def predict_se(
    trial: Trial,
    f,
    *,
    free,
    symmetric=(),
    statistic: str = "auto",
    numerics: Numerics | None = None,
    key=None,
    draws: int = 64,
    jacobian_draws: int = 8,
    calibration=None,
) -> PredictedSE:
    """Predicted standard errors of ``identify`` for a planned experiment.

    Args:
        trial: the experiment as planned: the true (or assumed) parameter values, and the
            noise it will meet (``Sensors``, ``VoluntaryForce``); its noise must be on.
        f: the perturbation ``F_Delta`` ``(N, 2)`` [N] (may be traced: ``jax.grad`` flows).
        free, symmetric, statistic: as ``identify`` (the efficient statistic is centred at the
            trial's own values). ``"auto"`` runs one noise-free simulation to choose, so it needs
            a concrete ``f``: under ``jax.grad`` or ``jit``, name the statistic.
        numerics: as ``identify`` (default ``IDENTIFY_NUMERICS``).
        key: ``jax.random`` key of the noise draws (default ``key(0)``).
        draws: as ``identify`` (its ``1 / R`` is in the prediction); also the draws behind
            ``Omega`` here, whose SEs then carry a Monte Carlo error of about ``1 / sqrt(2 R)``.
        jacobian_draws: as ``identify``.
        calibration: as ``identify``'s: its covariance carried into the prediction (the trial's
            values stay the planned truth's); needs a concrete ``f``.

    Returns a ``PredictedSE``.
    """
    require_x64("predict_se")
    if not isinstance(trial, Trial):
        raise ValueError(f"predict_se: trial must be a Trial (from make_trial), got {type(trial).__name__}")
    if not trial.noisy:
        raise ValueError("predict_se: the trial has no noise (ideal sensors, no voluntary force): nothing to predict")
    layout = lay.make_layout(free, symmetric, friction=trial.friction, where="predict_se")
    f = check_signal(trial, f, "predict_se")
    numerics, draws, jacobian_draws = check_sampling("predict_se", statistic, numerics, draws, jacobian_draws)
    if statistic == "auto":
        if not is_concrete(f):
            raise ValueError(
                'predict_se: statistic="auto" simulates to choose; under tracing name "efficient" or "welch"'
            )
        statistic = "efficient" if is_near_linear(trial, f, numerics) else "welch"
    efficient = statistic == "efficient" and indirect.arm_layout(layout) is not None
    key = jax.random.key(0) if key is None else key
    n_draws, n_jac = indirect.draw_counts(trial, draws, jacobian_draws)
    keys = jax.random.split(key, n_draws)
    p = lay.pack(layout, trial)
    if calibration is not None:  # refused before any simulation
        _check_calibration(calibration, trial, f, layout.names)
    weight = None
    if efficient and has_friction(trial):
        if not is_concrete(f):
            raise ValueError(
                "predict_se: the efficient statistic's weight under friction is simulated at a concrete f; under "
                'tracing use statistic="welch" (or crlb, the bound of the loop without friction)'
            )
        weight = jax.block_until_ready(
            indirect.statistic_weight(layout, trial, p, f, keys[: indirect.weight_draws(n_draws)], numerics)
        )
    if is_concrete(f) and has_friction(trial):  # identify's slope through friction is the chord: so is this one's
        cov, diverged = _chord_prediction(layout, trial, p, f, keys, n_jac, numerics, n_draws, efficient, weight)
    else:
        cov, diverged = _prediction(layout, trial, p, f, keys, keys[:n_jac], numerics, n_draws, efficient, weight)
    if calibration is not None:
        slope = (layout, trial, p, f, keys, n_jac, numerics, n_draws, efficient, weight)
        cov = cov + _calibration_share(*slope, calibration)
    if is_concrete(f):
        # one program in flight at a time: two programs that split over the CPU devices and
        # meet at collectives, queued together, can each hold a thread the other waits for
        cov, diverged = jax.block_until_ready((cov, diverged))
    return PredictedSE(
        se=lay.unflatten(layout, jnp.sqrt(jnp.diag(cov))),
        covariance=cov,
        labels=tuple(layout.labels()),
        diverged=diverged,
    )


def _draws_and_tangent(layout, trial, p, f, keys, jac_keys, numerics, efficient, weight):
    """``(arm statistic, draws' statistics, tangent slope, diverged)``: the arm's statistic
    (``efficient``, with ``weight``; else Welch), the draws and the binding's Jacobian."""
    arm_stat = indirect.arm_statistic(layout, trial, p, f, weight) if efficient else None
    stats, diverged = indirect.binding_draws(layout, trial, p, f, keys, numerics, arm_stat)
    jac, jac_diverged = indirect.binding_jacobian(layout, trial, p, f, jac_keys, numerics, arm_stat)
    return arm_stat, stats, jac, jnp.any(diverged) | jac_diverged


_draws_and_tangent_jit = jax.jit(_draws_and_tangent, static_argnames=("layout", "numerics", "efficient"))


@functools.partial(jax.jit, static_argnames=("layout", "numerics", "n_draws", "efficient"))
def _prediction(layout, trial, p, f, keys, jac_keys, numerics, n_draws, efficient, weight):
    """``(natural covariance, diverged)``: ``_draws_and_tangent`` and the covariance in one program."""
    _, stats, jac, diverged = _draws_and_tangent(layout, trial, p, f, keys, jac_keys, numerics, efficient, weight)
    g = lay.natural_jacobian(layout, p, trial)
    return g @ indirect.covariance(jac, stats, n_draws) @ g.T, diverged


def _chord_prediction(layout, trial, p, f, keys, n_jac, numerics, n_draws, efficient, weight):
    """``_prediction`` with ``identify``'s slope through friction: the binding's chord over +-1
    SE (the tangent's), on ``indirect.CHORD_DRAWS`` of the draws (``indirect.chord``). Concrete
    ``f`` only: under tracing ``predict_se`` keeps the tangent (its gradient is the tangent's)."""
    arm_stat, stats, tangent, diverged = _draws_and_tangent_jit(
        layout, trial, p, f, keys, keys[:n_jac], numerics, efficient, weight
    )
    stats, tangent = np.asarray(stats), np.asarray(tangent)
    half = np.sqrt(np.diag(np.asarray(indirect.covariance(tangent, stats, n_draws))))
    chord_keys = keys[: indirect.chord_draws(n_draws)]

    def means_at(points):
        return indirect.binding_means(layout, trial, points, f, chord_keys, numerics, arm_stat)

    slope = indirect.chord(means_at, np.asarray(p), half, tangent)
    g = lay.natural_jacobian(layout, p, trial)
    return g @ indirect.covariance(jnp.asarray(slope), jnp.asarray(stats), n_draws) @ g.T, diverged


def _calibration_share(layout, trial, p, f, keys, n_jac, numerics, n_draws, efficient, weight, calibration):
    """The calibration's share of the natural covariance (``calibration_prior``'s two-step term),
    through ``identify``'s slope (the chord through friction). Concrete ``f`` only."""
    cal = calibration_prior.checked(calibration, trial.friction, layout.names, trial.acquisition == "instant", "")
    cal = cal.without_names(layout.names)  # a calibrated name that is free is estimated, not held
    if not cal.labels:
        return np.zeros((len(layout.labels()),) * 2)
    arm_stat, stats, slope, _ = _draws_and_tangent_jit(
        layout, trial, p, f, keys, keys[:n_jac], numerics, efficient, weight
    )
    stats, slope = np.asarray(stats), np.asarray(slope)
    if has_friction(trial):
        half = np.sqrt(np.diag(np.asarray(indirect.covariance(slope, stats, n_draws))))
        chord_keys = keys[: indirect.chord_draws(n_draws)]

        def means_at(points):
            return indirect.binding_means(layout, trial, points, f, chord_keys, numerics, arm_stat)

        slope = indirect.chord(means_at, np.asarray(p), half, slope)
    _, sigma = calibration_prior.internal_covariance(cal, trial)
    chord_keys = keys[: indirect.chord_draws(n_draws)]
    a_c = calibration_prior.chord_columns(layout, trial, p, f, chord_keys, numerics, arm_stat, cal, sigma)
    aw = slope.T * np.asarray(indirect.weights(stats))[None, :]
    move = np.linalg.solve(aw @ slope, aw @ a_c)
    g = np.asarray(lay.natural_jacobian(layout, p, trial))
    return g @ move @ sigma @ move.T @ g.T


def _check_calibration(calibration, trial, f, free) -> None:
    if not is_concrete(f):
        raise ValueError("predict_se: calibration= needs a concrete f (its chord is simulated)")
    calibration_prior.check_robot(calibration, trial, "predict_se")
    calibration_prior.checked(calibration, trial.friction, free, trial.acquisition == "instant", "predict_se")
