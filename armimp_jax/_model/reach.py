"""What ``make_trial`` checks of a moving arm (docs/model.md, "The arm during a movement"), before
any simulation: the reach stays in the robot's workspace, the acquisition and the controller can
follow it, and the still arms it passes through (``snapshots``) are each a human arm's.
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np

from .._checks import is_concrete
from .arm import Arm
from .controllers.base import step_takes
from .movement import MinimumJerk, Profile
from .plausibility import arm_input_warning
from .robot import Robot, check_reach, fk, ik


def follows_path(controller) -> bool:
    """Whether a controller's ``step`` takes the planned set point (a ``path`` argument)."""
    return step_takes(controller, "path")


def check_moving(arm: Arm, controller, robot: Robot, acquisition: str, *, where: str = "make_trial") -> None:
    """Refuse, in one line, a moving arm the trial cannot simulate: a reach that leaves the robot's
    workspace, the box-car acquisition (its exact force mean holds for constant matrices only), a
    controller that cannot follow a planned path."""
    if acquisition != "instant":
        raise ValueError(f"{where}: a moving arm needs acquisition 'instant', got {acquisition!r}")
    if not follows_path(controller):
        raise ValueError(
            f"{where}: the controller {type(controller).__name__} cannot follow a moving arm: its step takes no "
            "path= argument (the planned set point, docs/extending.md)"
        )
    path = arm.endpoint
    if isinstance(path, MinimumJerk) and is_concrete((path.start, path.end, robot)):
        check_reach(path.start, path.end, robot, where=where)


def snapshot_times(arm: Arm) -> list[float]:
    """The times [s] at which a moving arm is checked: every profile knot, and a reach's start,
    middle and end (concrete values; sorted, unique)."""
    times = [0.0]
    for value in (arm.damping, arm.stiffness):
        if isinstance(value, Profile):
            times += np.asarray(value.times, dtype=float).tolist()
    if isinstance(arm.endpoint, MinimumJerk):
        onset, duration = float(np.asarray(arm.endpoint.onset)), float(np.asarray(arm.endpoint.duration))
        times += [onset, onset + 0.5 * duration, onset + duration]
    return sorted(set(times))


def snapshots(arm: Arm) -> list[tuple[float, Arm]]:
    """``(t, arm.at(t))`` at ``snapshot_times``: the still arms a moving arm passes through."""
    return [(t, arm.at(t)) for t in snapshot_times(arm)]


def motion_kind(arm: Arm) -> str:
    """How an arm moves, in words (trials that share a batch must agree): ``"still"``, or its path
    and each profile's number of knots."""
    if not arm.moving:
        return "still"
    parts = ["a reach" if isinstance(arm.endpoint, MinimumJerk) else "no reach"]
    for name in ("damping", "stiffness"):
        value = getattr(arm, name)
        parts.append(f"{name} of {value.knots} knots" if isinstance(value, Profile) else f"constant {name}")
    return ", ".join(parts)


def arm_warnings(arm: Arm, *, where: str = "make_trial") -> list[str]:
    """The plausibility warnings (``arm_input_warning``) of a concrete arm, or of each still arm a
    moving one passes through, each line once; none for a traced arm."""
    if arm.moving:
        still = [a for _, a in snapshots(arm)] if is_concrete(arm) else []
    else:
        still = [arm] if is_concrete((arm.mass, arm.damping, arm.stiffness)) else []
    lines = [w for a in still for w in arm_input_warning(a.mass, a.damping, a.stiffness, where=where)]
    return list(dict.fromkeys(lines))


def still_trials(trial) -> list:
    """The trials whose loops ``make_trial`` checks (``AbstractController.check_loop``): the trial
    itself for a still arm; for a concrete moving one, the still arm at each ``snapshot_times``,
    held at its own posture (the robot's loop changes along the reach); none for a traced one."""
    arm = trial.arm
    if not arm.moving:
        return [trial]
    out = []
    for _, still in snapshots(arm) if is_concrete(arm) else []:
        q = ik(jnp.asarray(still.endpoint), trial.robot)
        out.append(dataclasses.replace(trial, arm=still, q0=q, x0=fk(q, trial.robot)))
    return out
