"""A trial and its simulation loop (docs/model.md sections 5-7 and 15).

A trial is one record: the robot starts at rest at the arm's equilibrium, a perturbation
``F_Delta`` (``(N, 2)`` [N], one sample per control period) is added to the controller's
command, and the loop records what the acquisition sees. jax-md style, the simulation is
a pair of pure functions, ``simulate_init`` and ``simulate_chunk`` (an outer ``lax.scan``
over control periods: measure, control, integrate one period with the ``Numerics``'
solver, which scans its fixed substeps), and ``simulate`` runs them over a whole record.

``simulate`` is a single-trial function: batch it with ``jax.vmap`` over stacked trials
(``stack_trials``) and stacked perturbations. A batch may mix robots, arms, endpoints,
friction, gains and ``mhat``; the controller type, the acquisition and the period must
agree (they fix the program).
"""

from __future__ import annotations

import dataclasses
import warnings
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from ._checks import as_float64, check_choice, require_x64
from ._model.arm import Arm
from ._model.controllers import CONTROLLER_KINDS, AbstractController, Joints, matvec, reads_joints
from ._model.friction import FRICTION_KINDS, AbstractFriction
from ._model.movement import setpoint
from ._model.plant import PlantState, Trig, displacement, measure, near_path, plant_model, rest_state, trig_of
from ._model.reach import arm_warnings, check_moving, motion_kind, still_trials
from ._model.robot import MIT_MANUS, Robot, cartesian_inertia, fk, ik, jacobian_from_trig
from ._model.sensors import FORCE_HISTORY, IDEAL, Sensors, check_calibration, delayed_force, read_joints, sample_noise
from ._model.timing import CONTROL_PERIOD
from ._model.voluntary import VoluntaryForce, voluntary_init, voluntary_key, voluntary_normals, voluntary_update
from ._pytree import params
from ._solver.numerics import Numerics

ACQUISITIONS = ("instant", "interval_mean")
# A trial is flagged as diverged when its state is not finite or a joint has moved this
# far from its equilibrium [rad] (about 0.2 m at the handle; real trials move < 1 cm).
DIVERGENCE_ANGLE = 0.5
# During a reach, the same trigger as the hand's distance from the planned path [m].
DIVERGENCE_DISTANCE = 0.2


@params(static=("acquisition", "period"))
class Trial:
    """Everything that defines a trial except the perturbation (an immutable pytree; build it
    with ``make_trial``, which resolves and checks it).

    Leaves (float64, may be tracers): ``robot`` (``Robot``), ``arm`` (``Arm``), ``friction``
    (an ``AbstractFriction``: ``LuGre``, ``CoulombViscous`` or a user's law), ``controller``
    (a bound ``AbstractController``: ``PD``, ``IMBIC``, ``Admittance`` or a user's), ``sensors``
    (``Sensors``), and the equilibrium ``q0`` ``(2,)`` [rad] with ``x0 = fk(q0)`` ``(2,)``
    [m]; ``voluntary``, the person's own force (``VoluntaryForce``, or ``None``: a passive
    arm). Static: ``acquisition`` and the control ``period`` [s].
    """

    robot: Robot
    arm: Arm
    friction: AbstractFriction
    controller: AbstractController
    sensors: Sensors
    q0: jnp.ndarray
    x0: jnp.ndarray
    acquisition: str = "instant"
    period: float = CONTROL_PERIOD
    voluntary: VoluntaryForce | None = None

    @property
    def noisy(self) -> bool:
        """Whether a simulation of the trial draws noise (its sensors' or the person's force)."""
        return not (self.sensors.ideal and self.voluntary is None)


def _require(name, value, cls, what=None):
    if not isinstance(value, cls):
        raise ValueError(f"make_trial: {name} must be {what or 'a ' + cls.__name__}, got {type(value).__name__}")


def make_trial(
    controller: AbstractController,
    *,
    arm: Arm,
    friction: AbstractFriction,
    sensors: Sensors | None = None,
    robot: Robot | None = None,
    acquisition: str = "instant",
    period: float = CONTROL_PERIOD,
    voluntary: VoluntaryForce | None = None,
) -> Trial:
    """One trial's parameters.

    Args:
        controller: ``PD(...)``, ``IMBIC(...)``, ``Admittance(...)`` or any kind of
            ``AbstractController`` (``armimp_jax/_model/controllers/base.py``). Its defaults
            that depend on the equilibrium or the period (IMBIC's ``M_rd = M_x(q0)``, an
            admittance's discretised virtual model) are resolved here.
        arm: the human arm, with its equilibrium ``endpoint`` [m] in the world frame.
        friction: joint friction: ``LuGre(...)``, ``NO_FRICTION``, ``CoulombViscous(...)`` or
            any kind of ``AbstractFriction`` (``armimp_jax/_model/friction/base.py``).
        sensors: ``Sensors(...)``; default ideal.
        robot: ``Robot(...)``; default ``MIT_MANUS``.
        acquisition: ``"instant"`` (samples at ``t_k``, the paper's) or ``"interval_mean"``
            (box-car means over the period ending at ``t_k``).
        period: control and acquisition period ``L`` [s] (default 1 ms).
        voluntary: ``VoluntaryForce(std, cutoff)``, a random force the person applies to
            their own arm (unmeasured; docs/model.md section 17, ``_model/voluntary.py``); default
            none. It draws from ``simulate``'s key on a stream of its own.

    The robot starts at rest at ``q0 = ik(endpoint)`` (the branch ``0 < q1 - q2 < pi``);
    an endpoint it cannot reach, or reaches only near a singular posture, is refused
    with a ``ValueError``. Values may be tracers (``jax.vmap`` over ``mhat`` or an arm).
    A moving arm (a ``MinimumJerk`` endpoint, ``Profile`` damping or stiffness) starts at rest
    at its path's start; a reach that leaves the workspace, the ``"interval_mean"`` acquisition
    and a controller that cannot follow the path are refused (``_model/reach.py``).
    """
    require_x64("make_trial")
    _require("controller", controller, AbstractController, f"an AbstractController ({_kind_names(CONTROLLER_KINDS)})")
    _require("arm", arm, Arm)
    for line in arm_warnings(arm):  # a word, not a refusal: Arm's docstring says why
        warnings.warn(line, UserWarning, stacklevel=2)
    _require("friction", friction, AbstractFriction, f"an AbstractFriction ({_kind_names(FRICTION_KINDS)})")
    sensors = IDEAL if sensors is None else sensors
    _require("sensors", sensors, Sensors)
    robot = MIT_MANUS if robot is None else robot
    _require("robot", robot, Robot)
    check_choice("acquisition", acquisition, ACQUISITIONS)
    if not (isinstance(period, (int, float)) and not isinstance(period, bool) and period > 0):
        raise ValueError(f"make_trial: period must be a positive number of seconds, got {period!r}")
    check_calibration(sensors, acquisition, period)
    if voluntary is not None:
        _require("voluntary", voluntary, VoluntaryForce)
        if not voluntary.cutoff < 0.5 / period:
            raise ValueError(
                f"make_trial: voluntary cutoff must be below the Nyquist rate {0.5 / period:g} Hz, "
                f"got {voluntary.cutoff:g} Hz"
            )
    if arm.moving:
        check_moving(arm, controller, robot, acquisition)
    q0 = ik(jnp.asarray(arm.start), robot)
    x0 = fk(q0, robot)
    trial = Trial(
        robot=robot,
        arm=arm,
        friction=friction,
        controller=controller.bind(robot, q0, x0, period=float(period)),
        sensors=sensors,
        q0=q0,
        x0=x0,
        acquisition=acquisition,
        period=float(period),
        voluntary=voluntary,
    )
    for still in still_trials(trial):  # a moving arm's loop at each still arm it passes through
        trial.controller.check_loop(still)
    return trial


def _kind_names(registry) -> str:
    """The registered kinds' class names (for a refusal)."""
    return ", ".join(sorted(registry.get(n).__name__ for n in registry.names()))


def _align_sensors(trials: list[Trial]) -> list[Trial]:
    """Give every trial the union of the batch's sensor flags (a level of 0 then adds zeros)."""
    flags = [(t.sensors.force_on, t.sensors.encoder_on, t.sensors.velocity_on, t.sensors.calibrated) for t in trials]
    if len(set(flags)) == 1:
        return trials
    if len({f[1] for f in flags}) > 1:
        raise ValueError("stack_trials: trials with and without encoder quantisation cannot share a batch")
    force_on, velocity_on, calibrated = (any(f[i] for f in flags) for i in (0, 2, 3))
    out = []
    for t in trials:
        s = Sensors(
            t.sensors.force_noise,
            t.sensors.encoder_counts,
            t.sensors.velocity_noise,
            t.sensors.force_gain,
            t.sensors.force_offset,
            t.sensors.force_delay,
            t.sensors.force_model,
            t.sensors.force_friction,
            force_on=force_on,
            velocity_on=velocity_on,
            calibrated=calibrated,
        )
        out.append(dataclasses.replace(t, sensors=s))
    return out


def stack_trials(trials: list[Trial]) -> Trial:
    """Stack single trials along a new leading axis, for ``jax.vmap(simulate)``.

    The trials must share the controller type (and IMBIC's ``accel_estimate``), the
    acquisition and the period; sensor options are aligned (a trial whose noise is off
    gets a zero level).
    """
    trials = list(trials)
    if not trials:
        raise ValueError("stack_trials needs at least one Trial")
    for t in trials:
        if not isinstance(t, Trial):
            raise ValueError(f"stack_trials takes Trial values (from make_trial), got {type(t).__name__}")
    trials = _align_sensors(trials)
    cutoffs = {None if t.voluntary is None else t.voluntary.cutoff for t in trials}
    if len(cutoffs) > 1:
        raise ValueError(
            "trials in one batch must all have a voluntary force of one cutoff, or none; got cutoffs "
            f"{sorted(cutoffs, key=str)} (None: none)"
        )
    motions = {motion_kind(t.arm) for t in trials}
    if len(motions) > 1:
        raise ValueError(f"trials in one batch must move alike (a reach or none, the knots); got {sorted(motions)}")
    structures = {jax.tree.structure(t) for t in trials}
    if len(structures) > 1:
        force = lambda s: "motor" + " less a law" * (s.force_friction is not None) if s.motor_force else "transducer"  # noqa: E731
        kinds = sorted({(type(t.controller).__name__, t.acquisition, t.period, force(t.sensors)) for t in trials})
        raise ValueError(
            "trials in one batch must share the controller type and its static options, the acquisition, the period "
            f"and the hand force's reading; got (controller, acquisition, period, force) in {kinds}"
        )
    return jax.tree.map(lambda *xs: jnp.stack([jnp.asarray(x) for x in xs]), *trials)


class SimResult(NamedTuple):
    """What a trial records, one row per control sample ``k = 0..N-1`` (``t_k = k L``).

    ``x`` [m], ``fh`` [N]: what the acquisition records at ``t_k`` (world-frame position;
    hand force per docs/model.md section 7, sensor noise included). ``xd`` [m/s]: the measured
    velocity the controller used. ``q`` [rad], ``z`` [rad]: true joint angles and bristle
    states at ``t_k``. ``fu`` [N]: the command applied over ``[t_k, t_k+1)`` (it includes
    ``F_Delta``). All ``(N, 2)`` float64. ``diverged`` (bool) and ``diverged_at`` (int,
    first sample whose state was not finite or left the joint range, else -1): from that
    sample on, every field holds its last good value.
    """

    x: jnp.ndarray
    xd: jnp.ndarray
    fh: jnp.ndarray
    fu: jnp.ndarray
    q: jnp.ndarray
    z: jnp.ndarray
    diverged: jnp.ndarray
    diverged_at: jnp.ndarray


def check_perturbation(f_delta, *, where: str):
    arr = as_float64("f_delta", f_delta, where=where)
    if arr.ndim != 2 or arr.shape[1] != 2 or arr.shape[0] < 1:
        raise ValueError(f"f_delta must have shape (N, 2) with N >= 1 samples, got {arr.shape}")
    return arr


class SimCarry(NamedTuple):
    """Loop state between control periods: the plant state at ``t_k``; the command
    ``F_u,k-1`` and the true ``x_k-1``, ``xd_k-1`` (the acquisition's memory); the
    controller's memory; ``diverged_at`` (int32, -1 while the trial is sound) and ``k``,
    the next sample index; ``voluntary``, the person's force's memory (``VoluntaryState``;
    ``None`` without one); ``force_history`` ``(FORCE_HISTORY, 2)`` [N], the transducer's last
    true samples, newest first (the force channel's delay line; ``None`` unless the sensors are
    ``calibrated``)."""

    plant: PlantState
    fu_prev: jnp.ndarray
    x_prev: jnp.ndarray
    xd_prev: jnp.ndarray
    memory: Any
    diverged_at: jnp.ndarray
    k: jnp.ndarray
    voluntary: Any = None
    force_history: Any = None


def _check_trial(trial, where):
    require_x64(where)
    if not isinstance(trial, Trial):
        raise ValueError(f"{where}: trial must be a Trial (from make_trial), got {type(trial).__name__}")


def simulate_init(trial: Trial) -> SimCarry:
    """The loop state of a trial at ``t_0``: robot at rest at ``q0``, relaxed bristles."""
    zero = jnp.zeros_like(trial.x0)
    return SimCarry(
        rest_state(trial.q0),
        zero,
        trial.x0,
        zero,
        trial.controller.init(trial.x0),
        jnp.asarray(-1, dtype=jnp.int32),
        jnp.asarray(0, dtype=jnp.int32),
        None if trial.voluntary is None else voluntary_init(trial.x0),
        jnp.zeros((FORCE_HISTORY, 2), dtype=trial.x0.dtype) if trial.sensors.calibrated else None,
    )


class PeriodInputs(NamedTuple):
    """The random inputs of one control period, ``None`` where the trial draws none:
    ``force`` (2,) [N] and ``rate`` (2,) [rad/s], the force-sensor and joint-rate noise;
    ``voluntary`` (3, 2), the standard normals of the person's force (``voluntary_normals``);
    ``encoder`` (2,) [rad], an error added to the angle readings after quantisation (the
    simulation draws none: its encoders quantise; a linearisation puts the quantisation
    error here)."""

    force: Any = None
    rate: Any = None
    voluntary: Any = None
    encoder: Any = None


def period_inputs(trial: Trial, key, stream, k) -> PeriodInputs:
    """The draws of sample ``k``: sensor noise from ``fold_in(key, k)``, the person's force from
    ``stream = voluntary_key(key)``."""
    force, rate = sample_noise(trial.sensors, key, k)
    vol = None if trial.voluntary is None else voluntary_normals(stream, k)
    return PeriodInputs(force, rate, vol)


def _sense(trial: Trial, model, state: PlantState, x, xd, fh, inputs: PeriodInputs):
    """What the sensors report, from the true ``x``, ``xd``, ``F_h`` (unchanged when ideal)."""
    s = trial.sensors
    reads_angles = s.encoder_on or inputs.encoder is not None
    if reads_angles or s.velocity_on:
        q, qd = _joints_read(trial, state, inputs)
        if reads_angles:
            t = Trig(jnp.cos(q[0]), jnp.sin(q[0]), jnp.cos(q[1]), jnp.sin(q[1]))
            x = trial.x0 + jnp.stack(displacement(t, model))
        else:
            t = trig_of(state)
        j11, j12, j21, j22 = jacobian_from_trig(trial.robot, *t)
        xd = jnp.stack([j11 * qd[0] + j12 * qd[1], j21 * qd[0] + j22 * qd[1]])
    if s.calibrated:  # the transducer's gain: the controller reads it too
        fh = s.force_gain * fh
    if s.force_on:
        fh = fh + inputs.force
    return x, xd, fh


def _joints_read(trial: Trial, state: PlantState, inputs: PeriodInputs):
    """The joint angles and rates as the sensors read them (``read_joints``)."""
    q, qd = jnp.stack([state.q1, state.q2]), jnp.stack([state.qd1, state.qd2])
    return read_joints(trial.sensors, q, qd, inputs.encoder, inputs.rate)


def _command(trial: Trial, model, carry: SimCarry, state: PlantState, inputs: PeriodInputs, measured, fd, t_k):
    """``(F_u,k, memory)`` from the controller's ``step``: the measured samples, the planned set
    point during a reach, and the measured joint state where the kind's ``step`` takes it."""
    extra = {}
    if model.motion is not None and model.motion.path is not None:
        extra["path"] = setpoint(model.motion.path, t_k)
    if reads_joints(trial.controller):
        extra["joints"] = Joints(*_joints_read(trial, state, inputs), trial.robot)
    return trial.controller.step(carry.memory, *measured, fd, trial.x0, trial.period, **extra)


def _record(trial: Trial, state: PlantState, x, xd, fh, carry: SimCarry):
    """What the acquisition records at ``t_k`` from the true samples (before sensor noise)."""
    if trial.acquisition == "instant":
        return x, fh
    arm, x0, period = trial.arm, trial.x0, trial.period
    xbar = x0 + jnp.stack([state.xi1, state.xi2]) / period
    fbar = (
        matvec(arm.mass, (xd - carry.xd_prev) / period)
        + matvec(arm.damping, (x - carry.x_prev) / period)
        + matvec(arm.stiffness, xbar - x0)
    )
    if carry.voluntary is not None:  # F_v is held over the period: its mean is F_v,k-1
        fbar = fbar - carry.voluntary.force
    return xbar, fbar


def motor_force(trial: Trial, q, qd, xd, carry: SimCarry):
    """The hand force [N] ``(2,)`` a robot without a transducer computes from its motor torques:
    ``F_u,k-1 - M_x,model(q) (xd_k - xd_k-1) / L`` (``Sensors.force_model``), less ``J^-T
    tau_f,model(qd)`` where the lab subtracts a friction law (``Sensors.force_friction``)."""
    force = carry.fu_prev - matvec(cartesian_inertia(q, trial.sensors.force_model), (xd - carry.xd_prev) / trial.period)
    return force if trial.sensors.force_friction is None else force - trial.sensors.friction_force(q, qd)


def period_step(trial: Trial, model, numerics: Numerics, carry: SimCarry, fd, inputs: PeriodInputs):
    """One control period from ``carry`` under the perturbation sample ``fd`` (2,) [N] and the
    period's random ``inputs``: measure, control, integrate. Returns the new carry and the
    recorded row ``(x, xd, fh, fu, q, z)`` (as ``SimResult``'s fields). Pure; ``model`` is
    ``plant_model`` of the trial (hoisted out of the loop)."""
    state, k, period = carry.plant, carry.k, trial.period
    # The barriers make each sample one materialised value: otherwise XLA may recompute
    # it in several fusions whose FMA contraction differs (batched vs unbatched programs
    # then disagree in the last bit of the outputs).
    if carry.voluntary is None:
        applied = carry.fu_prev
    else:  # the person's F_v,k-1 pushes the robot like a command and the transducer reads -F_v
        applied = carry.fu_prev + carry.voluntary.force
    moving = model.motion is not None  # a moving arm's plant, set point and range check need the time
    t_k = carry.k.astype(trial.x0.dtype) * period if moving else None
    x, xd, fh = jax.lax.optimization_barrier(measure(*jax.lax.optimization_barrier((state, applied)), model, t_k))
    if carry.voluntary is not None:
        fh = fh - carry.voluntary.force
    if trial.sensors.motor_force:  # no transducer: the force from the motor torques, through the model
        fh = motor_force(trial, jnp.stack([state.q1, state.q2]), jnp.stack([state.qd1, state.qd2]), xd, carry)
    history = None
    x_rec, fh_rec = _record(trial, state, x, xd, fh, carry)
    if not trial.sensors.ideal or inputs.encoder is not None:
        x_m, xd_m, fh_m = _sense(trial, model, state, x, xd, fh, inputs)
        if trial.acquisition == "instant":
            x_rec, fh_rec = x_m, fh_m
            if trial.sensors.calibrated:  # the recorded force channel: gain, delay line, offset (model.md section 8)
                history = jnp.concatenate([fh[None], carry.force_history[:-1]])
                fh_rec = delayed_force(trial.sensors, history, period) + trial.sensors.force_offset
                fh_rec = fh_rec + inputs.force if trial.sensors.force_on else fh_rec
        elif trial.sensors.force_on:
            fh_rec = fh_rec + inputs.force
    else:
        x_m, xd_m, fh_m = x, xd, fh
    fu, memory = _command(trial, model, carry, state, inputs, (x_m, xd_m, fh_m), fd, t_k)
    fu, memory, x, xd = jax.lax.optimization_barrier((fu, memory, x, xd))
    zero = jnp.zeros_like(state.xi1)
    start = state._replace(xi1=zero, xi2=zero)
    if carry.voluntary is None:
        voluntary, push = None, fu
    else:
        voluntary, fv = voluntary_update(trial.voluntary, carry.voluntary, inputs.voluntary, k, period)
        push = fu + fv
    timed = {"time": t_k} if moving else {}  # a still arm's solvers are called as they always were
    new_state = numerics.solver.integrate_period(
        start, push, model, period=period, substeps=numerics.substeps, checkpoint=numerics.checkpoint, **timed
    )

    finite = jnp.all(jnp.stack([jnp.all(jnp.isfinite(leaf)) for leaf in jax.tree.leaves((new_state, fu))]))
    if moving and model.motion.path is not None:
        in_range = near_path(model, new_state, t_k + period, DIVERGENCE_DISTANCE)
    else:
        in_range = (jnp.abs(new_state.q1 - trial.q0[0]) < DIVERGENCE_ANGLE) & (
            jnp.abs(new_state.q2 - trial.q0[1]) < DIVERGENCE_ANGLE
        )
    diverged_at = jnp.where((carry.diverged_at < 0) & ~(finite & in_range), k + 1, carry.diverged_at)
    frozen = diverged_at >= 0
    new = (new_state, fu, x, xd, memory, voluntary, history)
    old = (state, carry.fu_prev, carry.x_prev, carry.xd_prev, carry.memory, carry.voluntary, carry.force_history)
    keep = jax.tree.map(lambda n, o: jnp.where(frozen, o, n), new, old)
    out = (x_rec, xd_m, fh_rec, fu, jnp.stack([state.q1, state.q2]), jnp.stack([state.z1, state.z2]))
    return SimCarry(*keep[:5], diverged_at, k + 1, *keep[5:]), out


def simulate_chunk(
    trial: Trial, carry: SimCarry, f_delta, *, key=None, numerics: Numerics | None = None
) -> tuple[SimCarry, SimResult]:
    """Run the samples ``f_delta`` ``(n, 2)`` [N] from ``carry``; returns the new carry and
    the ``n`` recorded rows. Chaining chunks gives bitwise the same numbers as one call of
    ``simulate`` (used for progress reporting and resumable long runs)."""
    _check_trial(trial, "simulate_chunk")
    numerics = Numerics() if numerics is None else numerics
    if not isinstance(numerics, Numerics):
        raise ValueError(f"numerics must be a Numerics, got {type(numerics).__name__}")
    f_delta = check_perturbation(f_delta, where="simulate_chunk")
    if (trial.sensors.force_on or trial.sensors.velocity_on) and key is None:
        raise ValueError("simulate: the trial's sensors draw noise; pass key=jax.random.key(seed)")
    if trial.voluntary is not None and key is None:
        raise ValueError("simulate: the trial's voluntary force is random; pass key=jax.random.key(seed)")
    if (trial.voluntary is None) != (carry.voluntary is None):
        raise ValueError("simulate_chunk: the carry does not match the trial's voluntary force (use simulate_init)")
    if trial.sensors.calibrated != (carry.force_history is not None):
        raise ValueError("simulate_chunk: the carry does not match the trial's force channel (use simulate_init)")
    model = plant_model(trial.q0, trial.x0, trial.arm, trial.friction, trial.robot)
    stream = None if trial.voluntary is None else voluntary_key(key)

    def control_period(carry: SimCarry, fd):
        return period_step(trial, model, numerics, carry, fd, period_inputs(trial, key, stream, carry.k))

    # What reverse mode keeps (inert when nothing is differentiated): with "period" the
    # tape holds one carry per period and the backward pass recomputes its substeps; with
    # "substep" the period is not checkpointed, so the tape holds every substep's carry.
    step = control_period if numerics.checkpoint == "substep" else jax.checkpoint(control_period, prevent_cse=False)
    carry, (x, xd, fh, fu, q, z) = jax.lax.scan(step, carry, f_delta)
    return carry, SimResult(x, xd, fh, fu, q, z, carry.diverged_at >= 0, carry.diverged_at)


def simulate(trial: Trial, f_delta, *, key=None, numerics: Numerics | None = None) -> SimResult:
    """Simulate one trial driven by the perturbation ``f_delta`` ``(N, 2)`` [N].

    Per sample ``k``: (1) measure ``x_k``, ``xd_k`` and ``F_h,k`` (with ``F_u,k-1`` still
    acting), (2) compute ``F_u,k``, (3) integrate to ``t_k+1`` with ``F_u,k`` held.

    Args:
        trial: from ``make_trial`` (or ``paper.trial``).
        f_delta: the perturbation ``(N, 2)`` [N], one sample per control period.
        key: a ``jax.random`` key for sensor noise (required when ``trial.sensors`` draws
            noise; ignored otherwise). Sample ``k`` uses ``fold_in(key, k)``.
        numerics: ``Numerics(...)``; default ``Numerics()``, GradedARK4 at 4 substeps, stable
            at any friction (``PAPER_NUMERICS``: the paper's RK4 at 100).

    Pure and single-trial: ``jax.vmap(simulate)`` batches it (trials from
    ``stack_trials``, keys from ``jax.random.split``), ``jax.grad`` flows through every
    float leaf of ``trial`` and through ``f_delta``.
    """
    _check_trial(trial, "simulate")
    return simulate_chunk(trial, simulate_init(trial), f_delta, key=key, numerics=numerics)[1]
