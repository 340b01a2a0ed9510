"""One optimisation loop for the package's gradient descents: experiment design on the bound
(``bound_design``) and by Monte Carlo (``monte_carlo_design``), and the Mhat tuner (``tuner``).

Each takes ``optimizer=``, an optax ``GradientTransformation`` (default: Adam at the caller's
learning rate, as before), and hands ``descend`` its own step: the guard that skips a step whose
draws diverged (Monte Carlo design), projects the gains back into the stable set (the bound's
design), or scales a step back when the training trials diverge (the tuner).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TypeVar

import optax

State = TypeVar("State")


def optimizer_or_default(optimizer, learning_rate: float, *, where: str) -> optax.GradientTransformation:
    """``optimizer`` (an optax ``GradientTransformation``), or Adam at ``learning_rate``; a
    one-line ``ValueError`` naming ``where`` for anything else."""
    if optimizer is None:
        return optax.adam(learning_rate)
    if not isinstance(optimizer, optax.GradientTransformation):
        raise ValueError(
            f"{where}: optimizer must be an optax GradientTransformation (optax.adam(0.1), say), got {optimizer!r}"
        )
    return optimizer


def descend(
    state: State,
    step: Callable[[State, int], State],
    steps: int,
    *,
    after: Callable[[State, int], None] | None = None,
    stop: Callable[[State], bool] | None = None,
    first: int = 0,
) -> State:
    """Steps ``first, ..., steps - 1``: ``state = step(state, i)``, then ``after(state, i)``;
    ends early when ``stop(state)`` holds before a step. Returns the last state."""
    for i in range(first, steps):
        if stop is not None and stop(state):
            break
        state = step(state, i)
        if after is not None:
            after(state, i)
    return state
