"""The design criterion: the targets' relative standard errors, per trial and aggregated over
trials (the worst or the mean), smoothed for a gradient by a log-sum-exp; and the
``DesignPlan`` that every design method holds fixed."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .._identification import layout as lay
from .._simulate import Trial

SOFTMAX_TEMPERATURE = 0.05  # in log relative SE: the smooth maximum is within ~0.05 * log(n) of the true one


class DesignPlan(NamedTuple):
    """What a design holds fixed, whatever its method: the ``trials`` designed for at once,
    the ``free`` parameters' names and ``layout``, the indices ``idx`` of the target entries,
    the ``Limits``, the ``criterion`` and its ``aggregate`` over the trials, the ``steps`` and
    ``learning_rate``, the ``key``, the ``progress`` callback (or None) and the ``optimizer``
    (an optax ``GradientTransformation``; ``descent.optimizer_or_default``)."""

    trials: list
    free: tuple
    layout: lay.Layout
    idx: list
    limits: object
    criterion: str
    aggregate: str
    steps: int
    learning_rate: float
    key: jax.Array
    progress: Callable[[int, int, float], None] | None
    optimizer: Any


def default_targets(layout) -> list[int]:
    """Indices of the default targets: every entry but the off-diagonals of a matrix, whose
    values may be near zero, so their relative SE is not a measure of precision."""
    return [i for i, lab in enumerate(layout.labels()) if not lab.endswith(("[0,1]", "[1,0]"))]


def relative_se(pred, trial: Trial, *, free, targets) -> dict:
    """``{label: SE / |value|}`` of the ``targets`` entries from ``pred`` (a ``PredictedSE`` of
    ``trial`` for the parameters ``free``), the values being ``trial``'s own."""
    layout = lay.make_layout(free, friction=trial.friction)
    labels = layout.labels()
    values = np.asarray(lay.natural_with_jacobian(layout, lay.pack(layout, trial), trial)[0])
    se = np.sqrt(np.diag(np.asarray(pred.covariance)))
    return {t: float(se[labels.index(t)] / abs(values[labels.index(t)])) for t in targets}


def _targets(layout, targets):
    """Indices into the natural vector of the ``targets`` labels (default: ``default_targets``)."""
    labels = layout.labels()
    if targets is None:
        return default_targets(layout)
    if isinstance(targets, str):
        targets = [targets]
    if not len(targets):
        raise ValueError("design: targets must name at least one entry (or be None)")
    bad = [t for t in targets if t not in labels]
    if bad:
        raise ValueError(f"design: unknown target {bad[0]!r}; the free parameters' entries are {', '.join(labels)}")
    return [labels.index(t) for t in targets]


def _criterion_value(cov, values, idx, criterion):
    """The criterion of one trial from its natural covariance and values: the log relative SEs
    ``(k,)`` (max_relative_se) or the log-determinant in relative units (d_optimal)."""
    idx = np.asarray(idx)
    sub = cov[idx][:, idx] / jnp.outer(jnp.abs(values[idx]), jnp.abs(values[idx]))
    if criterion == "d_optimal":  # per entry, in log SE like max_relative_se (half the log variance)
        return 0.5 * jnp.linalg.slogdet(sub)[1][None] / len(idx)
    return 0.5 * jnp.log(jnp.diag(sub))


def _aggregate(per_trial, criterion, aggregate, smooth: bool):
    """One number from the per-trial log criteria ``(T, k)``: a (smooth) maximum over the
    targets, then the worst or the mean over the trials; returned as a plain ratio (exp)."""
    per_trial = jnp.stack(per_trial)
    t = SOFTMAX_TEMPERATURE
    if criterion == "max_relative_se":
        inner = t * jax.nn.logsumexp(per_trial / t, axis=1) if smooth else jnp.max(per_trial, axis=1)
    else:
        inner = per_trial[:, 0]
    if aggregate == "worst":
        outer = t * jax.nn.logsumexp(inner / t) if smooth else jnp.max(inner)
    else:
        outer = jnp.mean(inner)
    return jnp.exp(outer)
