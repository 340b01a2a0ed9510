"""Sensor models (docs/model.md section 8): force noise, encoder quantisation, velocity noise, and
the force channel's calibration (gain, offset, delay).

Every option is off by default, and a trial with all options off computes no noise at
all, so its results are bitwise those of ideal sensors. The noise of sample ``k`` is drawn
from ``fold_in(key, k)``: the same key gives the same noise whatever the chunking of the
record, and different keys (seeds) give independent noise.

The controller and the acquisition see the same noisy samples. Under
``"interval_mean"`` acquisition (a documented choice): the recorded position is the exact
box-car mean of the true position (an integrating sensor: encoder quantisation and
velocity noise reach the controller only), and the recorded force is the exact box-car
mean of the transducer force plus the same force noise sample the controller sees.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from .._checks import as_param, check_range, is_concrete
from .._pytree import Param, params, replace_unchecked
from .friction.base import AbstractFriction
from .robot import Robot, jacobian


def _active(x) -> bool:
    """Whether a noise level needs the noise code: traced (it may be differentiated) or > 0."""
    return not is_concrete(x) or bool(np.any(np.asarray(x) != 0.0))


# The recorded force channel's delay line: the transducer's last samples kept in the loop's
# carry, so a delay up to (FORCE_HISTORY - 1) periods is read by linear interpolation.
FORCE_HISTORY = 8

# The schema every description of a trial reads: a TOML config's [sensors] section, a sweep
# point's settings (``--set``) and its table columns take ``SETTINGS`` (name -> unit, shape in a
# config, default); ``identify`` frees ``sensors.<name>`` of ``IDENTIFIABLE`` (name -> unit,
# shape, the optimiser's scale: "log" positive, "plain" as it is, "periods" over the control
# period). A field added to ``Sensors`` and named here reaches every one of them.
SETTINGS = dict(
    force_noise=("N", "pair", 0.0),
    encoder_counts=("counts/rev", "scalar", None),
    velocity_noise=("rad/s", "pair", 0.0),
)
IDENTIFIABLE = dict(
    force_gain=("-", (2,), "log"),
    force_offset=("N", (2,), "plain"),
    force_delay=("s", (), "periods"),
)


def static_settings(values) -> tuple:
    """What of a point's sensor ``SETTINGS`` changes the compiled program (batches group by it):
    whether the encoders quantise."""
    return (values["encoder_counts"] is not None,)


def _check_force_friction(law, motor_force: bool) -> None:
    """A law subtracted from the motor torques: a friction law without a bristle state, and only
    where the force comes from the motors."""
    if law is None:
        return
    if not isinstance(law, AbstractFriction):
        raise ValueError(f"Sensors: force_friction must be a friction law (CoulombViscous, say), got {law!r}")
    if not motor_force:
        raise ValueError(
            f"Sensors: force_friction {type(law).__name__} is subtracted from the motor torques: it needs force_model "
            "(a Robot)"
        )
    state = law.has_state()
    if is_concrete(state) and bool(np.any(np.asarray(state))):
        raise ValueError(
            f"Sensors: force_friction must be a static law (no bristle state), got {type(law).__name__}: "
            "use the calibration's RobotCalibration.friction(v_s)"
        )


@params(static=("force_on", "encoder_on", "velocity_on", "calibrated", "motor_force"))
class Sensors:
    """Sensor imperfections (an immutable pytree).

    Args:
        force_noise: standard deviation ``sigma_F`` [N] of white Gaussian noise on each axis
            of the force transducer (scalar or ``(2,)``), ``>= 0``.
        encoder_counts: encoder resolution [counts per revolution], ``>= 1``, or ``None``
            (exact angles). Joint angles are read as ``round(q / D) D``, ``D = 2 pi / counts``;
            the measured position and the Jacobian of the measured velocity use them.
        velocity_noise: standard deviation ``sigma_v`` [rad/s] of white Gaussian noise added
            to each joint rate before ``xd = J qd`` (scalar or ``(2,)``), ``>= 0``.
        force_gain: the force transducer's gain per axis (scalar or ``(2,)``), ``> 0``: the
            controller reads ``gain F_h`` and the recording ``gain F_h(t - delay) + offset``
            (each plus the force noise). Default 1.
        force_offset: the recorded force's offset [N] per axis (scalar or ``(2,)``); the
            controller's input is taken as tared (a documented choice, docs/model.md section 8).
            Default 0.
        force_delay: the recorded force's delay [s] behind the position channel (the
            acquisition's, not the controller's: a force delay inside IMBIC's loop makes it
            unstable, 1 ms already), ``>= 0`` and below ``(FORCE_HISTORY - 1)`` control periods
            (7 ms at 1 kHz); read by linear interpolation between samples. Default 0.
        force_model: a ``Robot``: the robot has no force transducer, and the hand force is
            computed from the commanded motor torques through this model of the robot,
            ``F = F_u,k-1 - M_x,model(q_k) a_k`` (``J^-T tau_motor`` less the model's inertial
            force; ``a_k = (xd_k - xd_k-1) / L``, the acceleration while ``F_u,k-1`` acted): what
            the controller and the recording read, plus the force noise. The robot's own
            friction and any error of the model stay in it: IMBIC, reading this force, cannot cancel
            the friction, and its joints stick as PD's do. Default ``None`` (a transducer).
        force_friction: with ``force_model``, the friction law the lab subtracts from the motor
            torques before the force is computed, ``F - J^-T tau_f,model(qd)`` (a static law
            such as the calibration's ``RobotCalibration.friction(v_s)``; no bristle state):
            what lets IMBIC cancel the friction without a transducer. Default ``None``.

    The static flags ``force_on``, ``encoder_on``, ``velocity_on`` and ``calibrated`` (any of
    gain, offset and delay not at its default, or traced; derived, not arguments) say which
    options the simulation computes; ``stack_trials`` aligns them across a batch.
    """

    force_noise: Param = 0.0
    encoder_counts: Param | None = None
    velocity_noise: Param = 0.0
    force_gain: Param = 1.0
    force_offset: Param = 0.0
    force_delay: Param = 0.0
    force_model: object = None
    force_friction: object = None
    force_on: bool = False
    encoder_on: bool = False
    velocity_on: bool = False
    calibrated: bool = False
    motor_force: bool = False

    def __post_init__(self):
        w = "Sensors"
        set_ = object.__setattr__
        set_(self, "force_noise", as_param("force_noise [N]", self.force_noise, (2,), where=w, broadcast=True))
        set_(
            self,
            "velocity_noise",
            as_param("velocity_noise [rad/s]", self.velocity_noise, (2,), where=w, broadcast=True),
        )
        set_(self, "force_noise", check_range("force_noise", self.force_noise, where=w, minimum=0.0, unit=" N"))
        set_(
            self,
            "velocity_noise",
            check_range("velocity_noise", self.velocity_noise, where=w, minimum=0.0, unit=" rad/s"),
        )
        counts = self.encoder_counts
        if counts is not None:
            counts = as_param("encoder_counts [counts/rev]", counts, (), where=w)
            counts = check_range("encoder_counts", counts, where=w, minimum=1.0, unit=" counts per revolution")
        set_(self, "encoder_counts", counts)
        set_(self, "force_gain", as_param("force_gain", self.force_gain, (2,), where=w, broadcast=True))
        set_(self, "force_gain", check_range("force_gain", self.force_gain, where=w, minimum=0.0, exclusive=True))
        set_(self, "force_offset", as_param("force_offset [N]", self.force_offset, (2,), where=w, broadcast=True))
        delay = as_param("force_delay [s]", self.force_delay, (), where=w)
        set_(self, "force_delay", check_range("force_delay", delay, where=w, minimum=0.0, unit=" s"))
        calibration = (self.force_gain - 1.0, self.force_offset, self.force_delay)
        set_(self, "calibrated", bool(self.calibrated) or any(_active(v) for v in calibration))
        if self.force_model is not None and not isinstance(self.force_model, Robot):
            raise ValueError(f"Sensors: force_model must be a Robot (the model of the robot), got {self.force_model!r}")
        set_(self, "motor_force", self.force_model is not None)
        _check_force_friction(self.force_friction, self.motor_force)
        set_(self, "force_on", bool(self.force_on) or _active(self.force_noise))
        set_(self, "velocity_on", bool(self.velocity_on) or _active(self.velocity_noise))
        set_(self, "encoder_on", counts is not None)

    def friction_force(self, q, qd):
        """The Cartesian force [N] ``(2,)`` of the friction law the lab subtracts
        (``force_friction``) at joint angles ``q`` [rad] and rates ``qd`` [rad/s]: ``J^-T tau_f(qd)``,
        ``tau_f = static_torque + viscous qd``, through ``force_model``'s Jacobian."""
        law = self.force_friction
        tau = jnp.stack(
            [law.joint(i).static_torque(qd[i]) + law.joint(i).viscous_coefficient() * qd[i] for i in (0, 1)]
        )
        return jnp.linalg.solve(jacobian(q, self.force_model).T, tau)

    @property
    def ideal(self) -> bool:
        return not (self.force_on or self.encoder_on or self.velocity_on or self.calibrated or self.motor_force)


IDEAL = Sensors()


def quiet(sensors: Sensors) -> Sensors:
    """The sensors of a noise-free run (a prediction, a check of the loop): ideal, but a force
    from the motor torques stays one (its model robot and subtracted law change what a controller
    that reads the force does)."""
    if not sensors.motor_force:
        return IDEAL
    return replace_unchecked(
        IDEAL, force_model=sensors.force_model, force_friction=sensors.force_friction, motor_force=True
    )


def sample_noise(sensors: Sensors, key, k):
    """The noise of sample ``k``: ``(force (2,) [N], joint rate (2,) [rad/s])``; zeros when off
    (statically: no random numbers are drawn)."""
    if not (sensors.force_on or sensors.velocity_on):
        return None, None
    normal = jax.random.normal(jax.random.fold_in(key, k), (2, 2), dtype=jnp.float64)
    force = sensors.force_noise * normal[0] if sensors.force_on else None
    rate = sensors.velocity_noise * normal[1] if sensors.velocity_on else None
    return force, rate


@jax.custom_jvp
def _round_to(q, step):
    return jnp.round(q / step) * step


@_round_to.defjvp
def _round_to_jvp(primals, tangents):
    # The reading's derivative is that of its mean over a dither (the identity), not
    # round's zero: a gradient through an encoder then follows the motion it measures.
    q, step = primals
    return _round_to(q, step), tangents[0]


def quantise(q, sensors: Sensors):
    """Encoder reading ``round(q / D) D`` [rad] of a joint angle (identity when off).

    Differentiated as the identity (the derivative of the reading's mean over a sub-count
    dither): ``round``'s own derivative is zero almost everywhere, which would make every
    gradient and Jacobian through an encoder blind to the joint's motion."""
    if not sensors.encoder_on:
        return q
    return _round_to(q, 2.0 * jnp.pi / sensors.encoder_counts)


def read_joints(sensors: Sensors, q, qd, encoder=None, rate=None):
    """The joint angles [rad] and rates [rad/s] ``(2,)`` as the sensors read them: the encoders'
    reading plus its offset draw ``encoder`` (when reading angles), the rates plus the rate
    noise draw ``rate`` (when the rate sensors are on)."""
    if sensors.encoder_on or encoder is not None:
        q = quantise(q, sensors)
        if encoder is not None:
            q = q + encoder
    if sensors.velocity_on:
        qd = qd + rate
    return q, qd


def delayed_force(sensors: Sensors, history, period: float):
    """The transducer's reading ``gain F_h(t - delay)`` [N] ``(2,)`` from ``history``
    ``(FORCE_HISTORY, 2)``, the true force's last samples, newest first: linear interpolation
    between samples (weights ``max(0, 1 - |i - delay / period|)``, differentiable in the delay)."""
    lag = jnp.clip(sensors.force_delay / period, 0.0, FORCE_HISTORY - 1.0)
    i = jnp.arange(FORCE_HISTORY, dtype=history.dtype)
    w = jnp.maximum(0.0, 1.0 - jnp.abs(i - lag))
    return sensors.force_gain * (w[:, None] * history).sum(axis=0)


def check_calibration(sensors: Sensors, acquisition: str, period: float) -> None:
    """The force channel's calibration, or a force from the motor torques, needs the instant
    acquisition, and a delay the delay line holds."""
    if sensors.motor_force and acquisition != "instant":
        raise ValueError(f"make_trial: a force from the motor torques needs acquisition 'instant', got {acquisition!r}")
    if not sensors.calibrated:
        return
    if acquisition != "instant":
        raise ValueError(
            f"make_trial: the force channel's gain, offset and delay need acquisition 'instant', got {acquisition!r}"
        )
    longest = (FORCE_HISTORY - 1) * period
    if is_concrete(sensors.force_delay) and not float(sensors.force_delay) < longest:
        raise ValueError(
            f"make_trial: Sensors force_delay must be below {longest:g} s ({FORCE_HISTORY - 1} periods), "
            f"got {float(sensors.force_delay):g} s"
        )
