"""The tuner on disk: a ``TuneState`` as one checked record (``state_arrays``; ``save_state``
writes it atomically with the settings that produced it, ``config_settings`` plus the
caller's description of the training batch; ``load_state`` refuses a file that is torn,
altered, or was saved with other settings). The tuning itself (parameterisation, loss,
gradients, the optimiser's steps) is pure JAX in ``armimp_jax._design.tuner``,
re-exported here; the paper's experiment, a specification of the study engine with one
record per iteration, is ``armimp_jax.paper.mhat_experiment``.
"""

from __future__ import annotations

import pathlib

import jax
import jax.numpy as jnp
import numpy as np

from ..._design.descent import optimizer_or_default
from ..._design.tuner import (
    MAX_START_SHRINKS,
    PARAMETERISATIONS,
    History,
    LossAux,
    Trainer,
    TuneConfig,
    TuneState,
    batch_loss,
    config_settings,
    make_trainer,
    mhat_from_theta,
    n_parameters,
    place_batch,
    start_state,
    step_state,
    theta_from_mhat,
    trial_loss,
    tune,
    value_and_grad_fn,
    with_mhat,
)
from ..runs.results import ResultsError, load_record, save_record

__all__ = [
    "MAX_START_SHRINKS",
    "PARAMETERISATIONS",
    "History",
    "LossAux",
    "Trainer",
    "TuneConfig",
    "TuneState",
    "batch_loss",
    "config_settings",
    "make_trainer",
    "mhat_from_theta",
    "n_parameters",
    "place_batch",
    "start_state",
    "step_state",
    "theta_from_mhat",
    "trial_loss",
    "tune",
    "value_and_grad_fn",
    "with_mhat",
    "state_arrays",
    "state_from_arrays",
    "save_state",
    "load_state",
]


def state_arrays(state: TuneState) -> dict:
    """``state`` as the named arrays of a record, and the notes of its meta."""
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
    return arrays, dict(iteration=state.iteration, value=state.value, rejected=state.rejected)


def save_state(path: pathlib.Path, state: TuneState, settings: dict, *, meta: dict | None = None) -> str:
    """Save ``state`` atomically as one checked record (``armimp_jax.study.runs.results``) with the
    ``settings`` that produced it (``config_settings`` plus the caller's description of the
    training problem); returns their key. ``meta``: further JSON-able notes."""
    arrays, notes = state_arrays(state)
    return save_record(path, settings=settings, arrays=arrays, meta=notes | dict(meta or {}))


def load_state(path: pathlib.Path, settings: dict, config: TuneConfig, *, optimizer=None) -> TuneState:
    """The ``TuneState`` saved in ``path``, checked: a ``ResultsError`` names the file when it
    is missing, truncated or altered, or was saved with other ``settings`` (the message
    lists the differences). ``optimizer``: the one ``tune`` was given (default Adam)."""
    arrays = load_record(path, settings=settings).arrays
    return state_from_arrays(arrays, config, where=str(path), optimizer=optimizer)


def state_from_arrays(a: dict, config: TuneConfig, *, where: str, optimizer=None) -> TuneState:
    """The ``TuneState`` of a record's arrays (``state_arrays``), for ``optimizer`` (default Adam
    at ``config.learning_rate``); a ``ResultsError`` naming ``where`` when they hold another
    optimiser's state."""
    try:
        theta = jnp.asarray(a["theta"])
        template = optimizer_or_default(optimizer, config.learning_rate, where="tune").init(theta)
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
        raise ResultsError(f"{where}: not a tuning state of this config ({err.args[0]})") from None
