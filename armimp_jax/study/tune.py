"""Saving and resuming a tuning run: ``save_state`` writes a ``TuneState`` atomically as one
checked record together with the settings that produced it (``config_settings`` plus the
caller's description of the training batch), and ``load_state`` refuses a file that is
torn, altered, or was saved with other settings. The tuning itself (parameterisation,
loss, gradients, the optimiser loop) is pure JAX in ``armimp_jax._identification.tune``,
re-exported here; the paper's experiment is ``armimp_jax.paper.tune``.
"""

from __future__ import annotations

import pathlib

import jax
import jax.numpy as jnp
import numpy as np
import optax

from .._identification.tune import (
    MAX_START_SHRINKS,
    PARAMETERISATIONS,
    History,
    LossAux,
    TuneConfig,
    TuneState,
    batch_loss,
    config_settings,
    mhat_from_theta,
    n_parameters,
    place_batch,
    theta_from_mhat,
    trial_loss,
    tune,
    value_and_grad_fn,
    with_mhat,
)
from .results import ResultsError, load_record, save_record

__all__ = [
    "MAX_START_SHRINKS",
    "PARAMETERISATIONS",
    "History",
    "LossAux",
    "TuneConfig",
    "TuneState",
    "batch_loss",
    "config_settings",
    "mhat_from_theta",
    "n_parameters",
    "place_batch",
    "theta_from_mhat",
    "trial_loss",
    "tune",
    "value_and_grad_fn",
    "with_mhat",
    "save_state",
    "load_state",
]


def save_state(path: pathlib.Path, state: TuneState, settings: dict, *, meta: dict | None = None) -> str:
    """Save ``state`` atomically as one checked record (``armimp_jax.study.results``) with the
    ``settings`` that produced it (``config_settings`` plus the caller's description of the
    training problem); returns their key. ``meta``: further JSON-able notes."""
    arrays = dict(
        theta=np.asarray(state.theta),
        grad=np.asarray(state.grad),
        value=np.asarray(state.value, dtype=float),
        iteration=np.asarray(state.iteration, dtype=int),
        step_scale=np.asarray(state.step_scale, dtype=float),
        rejected=np.asarray(state.rejected, dtype=int),
        **{f"opt_state.{i}": np.asarray(x) for i, x in enumerate(jax.tree.leaves(state.opt_state))},
        **{f"history.{k}": v for k, v in state.history._asdict().items()},
    )
    notes = dict(iteration=state.iteration, value=state.value, rejected=state.rejected) | dict(meta or {})
    return save_record(path, settings=settings, arrays=arrays, meta=notes)


def load_state(path: pathlib.Path, settings: dict, config: TuneConfig) -> TuneState:
    """The ``TuneState`` saved in ``path``, checked: a ``ResultsError`` names the file when it
    is missing, truncated or altered, or was saved with other ``settings`` (the message
    lists the differences)."""
    rec = load_record(path, settings=settings)
    a = rec.arrays
    try:
        theta = jnp.asarray(a["theta"])
        template = optax.adam(config.learning_rate).init(theta)
        leaves = jax.tree.leaves(template)
        saved = [a[f"opt_state.{i}"] for i in range(len(leaves))]
        if f"opt_state.{len(leaves)}" in a or any(np.shape(x) != np.shape(t) for x, t in zip(saved, leaves)):
            raise KeyError("optimiser state of another shape")
        history = History(**{k: a[f"history.{k}"] for k in History._fields})
        return TuneState(
            theta=theta,
            opt_state=jax.tree.unflatten(jax.tree.structure(template), [jnp.asarray(x) for x in saved]),
            grad=jnp.asarray(a["grad"]),
            value=float(a["value"]),
            iteration=int(a["iteration"]),
            step_scale=float(a["step_scale"]),
            rejected=int(a["rejected"]),
            history=history,
        )
    except KeyError as err:
        raise ResultsError(f"{path}: not a tuning state of this config ({err.args[0]})") from None
