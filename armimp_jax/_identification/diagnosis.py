"""What a recording's motion says about whether it can tell the arm: ``motion_diagnosis``; and
whether ``identify``'s answer could be a human arm's: ``plausibility``.

Under PD with joint friction the joints can stick for most of a record: the hand then hardly
moves, the recording shows the robot's friction rather than the arm, and a fit through the
model fails or gives useless intervals. The optimiser's state ("no step lowered the
mismatch") does not tell a lab what to change; the share of the record each joint stood
still does. Joint rates come from the recorded hand position (inverse kinematics of ``x``
smoothed at ``SMOOTHING_HZ``, which removes the encoder steps), and a joint counts as
standing still below ``STUCK_SPEED`` (twice LuGre's usual Stribeck velocity; a joint in
pre-sliding moves micrometres). Measured on simulated recordings with 2^18-count encoders:
the share matched the true one within 0.05 (PD at 0.3 and 0.8 N m, level-1 perturbation),
and a frictionless loop read 0.02-0.04.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .._estimation.plausibility import plausibility_warnings
from .._model.controllers.imbic import IMBIC
from .._model.robot import ik
from .auxiliary import lowpass
from .layout import ARM_PARAMETERS

STUCK_SPEED = 2e-3  # [rad/s]
SMOOTHING_HZ = 10.0
STUCK_ADVICE = 0.3  # a share of the record above which the advice is given
EDGE = 200  # samples left out at each end (the smoothing's wrap-around)


class Motion(NamedTuple):
    """``fraction`` ``(2,)``: the share of the record each joint stood still; ``advice``: lines
    for a lab (empty when the joints moved)."""

    fraction: np.ndarray
    advice: list


@jax.jit
def _joint_rates(trial, x):
    q = jax.vmap(lambda v: ik(v, trial.robot))(lowpass(x, trial.period, SMOOTHING_HZ))
    return jnp.gradient(q, trial.period, axis=0)


def motion_diagnosis(trial, x) -> Motion:
    """How long each joint of ``trial``'s robot stood still in the recorded ``x`` ``(N, 2)`` [m]."""
    qd = np.asarray(_joint_rates(trial, jnp.asarray(x)))
    inner = qd[EDGE:-EDGE] if qd.shape[0] > 4 * EDGE else qd
    fraction = np.mean(np.abs(inner) < STUCK_SPEED, axis=0)
    advice = []
    if np.max(fraction) > STUCK_ADVICE:
        advice.append(
            f"the joints stood still for {np.max(fraction):.0%} of the record (joint 1 {fraction[0]:.0%}, joint 2 "
            f"{fraction[1]:.0%}): the robot's friction held them, so the recording shows little of the arm; "
            + _remedy(trial)
        )
    return Motion(fraction, advice)


def _remedy(trial) -> str:
    """What to change, by what held the joints: a force read from the motors carries the
    friction into the controller unless the lab subtracts its law, so IMBIC cannot cancel it
    (measured: 87% of a record stuck, against 5% with the law subtracted and 6% with a
    transducer; model.md section 8.2)."""
    larger = "record with a larger perturbation or one in bursts (ShapedNoise(duty=...))"
    s = trial.sensors
    if s.motor_force and s.force_friction is None:
        return (
            "the hand force is read from the motor torques (Sensors.force_model), so the friction is inside it and "
            "the controller cannot compensate it: subtract the calibrated friction law "
            f"(Sensors(force_friction=calibration.friction(v_s))) or fit a force transducer, or {larger}"
        )
    return larger if isinstance(trial.controller, IMBIC) else f"{larger}, or under IMBIC"


def plausibility(values: dict, se: dict) -> list[str]:
    """Per group of recordings, a warning where its arm's estimated diagonals are no human
    arm's (``plausibility_warnings``: a mass outside 0.05-10 kg, a negative damping or
    stiffness, beyond what their 95% intervals reach), with the likely cause; ``values``, ``se``: ``{name: array}`` as
    ``Identification``'s (``"arm.mass"`` or ``"arm.mass@<group>"``)."""
    groups: dict[str, dict] = {}
    for name, value in values.items():
        base, _, group = name.partition("@")
        if base in ARM_PARAMETERS:
            groups.setdefault(group, {})[base.split(".")[1]] = (value, se[name])
    out = []
    for group, found in groups.items():
        suffix = f"@{group}" if group else ""
        out += plausibility_warnings(
            {m: v for m, (v, _) in found.items()},
            {m: s for m, (_, s) in found.items()},
            label=lambda matrix, axis, suffix=suffix: f"arm.{matrix}{suffix}[{axis},{axis}]",
            beyond_noise=True,  # an interval that reaches plausible values stands: no warning
        )
    return out
