"""The closed loop linearised about its rest: one control period as a discrete-time state space.

Near rest the whole sampled loop (plant, integrator, sensors, controller, acquisition and the
person's force filter) is one linear map per control period,

    s_k+1 = A s_k + B u_k,        y_k = C s_k + D u_k,

obtained by forward-mode differentiation of the simulator's own period step
(``_simulate.period_step``) at the rest state, so it is the simulation's loop to first
order, with its zero-order holds, its instant or interval-mean samples, its sensors and its
controller; the plant's period is integrated exactly (``_ExactPlant``), where the simulation
uses its integrator (they agree to the integrator's truncation). ``s`` is every float of the
loop's carry; the inputs ``u`` are ``INPUTS``: the perturbation ``F_Delta`` [N], then the
noise of one period: force-sensor noise [N], joint rate noise [rad/s], the encoders'
quantisation error as an angle [rad] (white, variance ``D^2 / 12``: the reading's error over
a motion of many counts) and the white driver of the person's force (unitless). The outputs
``y`` are the recorded ``x - x0`` [m] and ``F_h`` [N].

What it gives, all pure JAX and differentiable in every float of the trial (gains, arm,
robot, noise levels) and in the perturbation: the deterministic response to ``F_Delta`` from
rest (``respond``), the noise's stationary covariance (``stationary_cov``; the hand's drift
under the person's force, ``drift``) and the loop's stability (``spectral_radius``); the
noise's own Kalman filter is in ``kalman.py``. The loop is linearised without its Coulomb
friction (``without_friction``: no bristles, the viscous part kept): at rest LuGre's
bristles would be a stiff spring (a static law's ``tanh`` a huge damper), the joints stuck,
which is no linear model of a moving robot.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree

from .._model.plant import PlantState, plant_derivative, plant_model
from .._model.sensors import Sensors
from .._pytree import replace_unchecked
from .._simulate import PeriodInputs, Trial, period_step, simulate_init

# Input groups of ``u``, two entries each (x and y axes, or joints 1 and 2)
INPUTS = ("f_delta", "force_noise", "rate_noise", "encoder_error", "voluntary")
OUTPUTS = ("x1", "x2", "fh1", "fh2")
# The linearisation routes every sensor's noise through an input; their levels live in ``noise_var``.
_ROUTED = Sensors(force_on=True, velocity_on=True)


class LinearLoop(NamedTuple):
    """The loop linearised about rest (a pytree of arrays; ``jax.vmap`` stacks them).

    ``a`` ``(n, n)``, ``b`` ``(n, 10)``, ``c`` ``(4, n)``, ``d`` ``(4, 10)``: the state space
    above, inputs in the order of ``INPUTS`` (two each), outputs ``OUTPUTS``. ``noise_var``
    ``(8,)``: the per-sample variance of each noise input (``u[2:]``): ``sigma_F^2`` [N^2],
    ``sigma_v^2`` [rad^2/s^2], ``D^2 / 12`` [rad^2] (0 without encoders), 1 (0 without the
    person's force). ``rest`` ``(4,)``: the recorded outputs at rest where the recorded force
    has an offset (calibrated sensors), else ``None`` (zero)."""

    a: jnp.ndarray
    b: jnp.ndarray
    c: jnp.ndarray
    d: jnp.ndarray
    noise_var: jnp.ndarray
    rest: jnp.ndarray | None = None


def without_friction(trial: Trial) -> Trial:
    """``trial`` without its Coulomb and Stribeck friction (the law's ``without_coulomb``: no
    bristles), its viscous friction kept (linear): the loop IMBIC promises to leave."""
    return replace_unchecked(trial, friction=trial.friction.without_coulomb())


def _routed(sensors: Sensors) -> Sensors:
    """The linearisation's sensors: every noise routed through an input, the force channel's
    calibration (gain, delay line, offset) kept, and a force from the motor torques (its model
    robot, and the subtracted law's viscous part: its Coulomb part dropped, as the plant's is)."""
    routed = _ROUTED
    if sensors.calibrated:
        gain, offset, delay = sensors.force_gain, sensors.force_offset, sensors.force_delay
        routed = replace_unchecked(routed, force_gain=gain, force_offset=offset, force_delay=delay, calibrated=True)
    if sensors.motor_force:
        law = sensors.force_friction
        law = None if law is None else law.without_coulomb()
        routed = replace_unchecked(routed, force_model=sensors.force_model, force_friction=law, motor_force=True)
    return routed


def _noise_variances(trial: Trial):
    s = trial.sensors
    zero = jnp.zeros(2)
    force = s.force_noise**2 if s.force_on else zero
    rate = s.velocity_noise**2 if s.velocity_on else zero
    if s.encoder_on:
        step = 2.0 * jnp.pi / s.encoder_counts
        encoder = jnp.full(2, step * step / 12.0)
    else:
        encoder = zero
    voluntary = zero if trial.voluntary is None else jnp.ones(2)
    return jnp.concatenate([force, rate, encoder, voluntary])


# Without Coulomb friction the bristle states z1, z2 (entries 4, 5 of the plant state) never move: they
# are left out of ``s`` (an eigenvalue of 1 that neither the inputs nor the outputs see would
# leave the Kalman filter's Riccati equation without a solution).
_BRISTLES = slice(4, 6)


def _drop_bristles(s):
    return jnp.concatenate([s[: _BRISTLES.start], s[_BRISTLES.stop :]])


def _with_bristles(s):
    return jnp.concatenate([s[: _BRISTLES.start], jnp.zeros(2, s.dtype), s[_BRISTLES.start :]])


class _ExactPlant(NamedTuple):
    """One control period of the plant linearised about ``rest`` under the rest command (zero),
    integrated exactly (a zero-order hold: ``s' = rest + Phi (s - rest) + Gamma fu``, from one
    matrix exponential). The integrators' truncation error is not in it, and neither is their
    cost: differentiating through a period of ``GradedARK4`` twice (a linearisation, then its
    derivative in the arm) took minutes to compile."""

    rest: PlantState

    def integrate_period(self, s, fu, model, *, period, substeps, checkpoint):
        rest_flat, unravel = ravel_pytree(self.rest)
        zero = jnp.zeros(2, dtype=rest_flat.dtype)

        def derivative(x, u):
            return ravel_pytree(plant_derivative(unravel(x), u, model))[0]

        ac, bc = jax.jacfwd(derivative, argnums=(0, 1))(rest_flat, zero)
        n = ac.shape[0]
        generator = jnp.zeros((n + 2, n + 2), dtype=ac.dtype).at[:n, :n].set(ac).at[:n, n:].set(bc)
        hold = jax.scipy.linalg.expm(generator * period)
        moved = hold[:n, :n] @ (ravel_pytree(s)[0] - rest_flat) + hold[:n, n:] @ fu
        return unravel(rest_flat + moved)


class _ExactNumerics(NamedTuple):
    """What ``period_step`` reads of a ``Numerics``, holding the exact period of ``_ExactPlant``."""

    solver: _ExactPlant
    substeps: int = 1
    checkpoint: str = "period"


def linearise(trial: Trial) -> LinearLoop:
    """The trial's loop without its Coulomb friction, linearised about rest (module docstring).

    Single-trial and traceable: ``jax.vmap`` over stacked trials, ``jax.grad`` / ``jax.jacfwd``
    through any float of ``trial``.
    """
    routed = replace_unchecked(without_friction(trial), sensors=_routed(trial.sensors))
    model = plant_model(routed.q0, routed.x0, routed.arm, routed.friction, routed.robot)
    rest = simulate_init(routed)
    rest = rest._replace(k=jnp.asarray(1, dtype=jnp.int32))  # past the person's force's start
    exact = _ExactNumerics(_ExactPlant(rest.plant))
    floats = (rest.plant, rest.fu_prev, rest.x_prev, rest.xd_prev, rest.memory, rest.voluntary, rest.force_history)
    s0, unravel = ravel_pytree(floats)
    s0 = _drop_bristles(s0)
    with_voluntary = trial.voluntary is not None

    def period(s, u):
        plant, fu_prev, x_prev, xd_prev, memory, voluntary, history = unravel(_with_bristles(s))
        carry = rest._replace(
            plant=plant,
            fu_prev=fu_prev,
            x_prev=x_prev,
            xd_prev=xd_prev,
            memory=memory,
            voluntary=voluntary,
            force_history=history,
        )
        normals = jnp.concatenate([u[8:10][None], jnp.zeros((2, 2), u.dtype)]) if with_voluntary else None
        inputs = PeriodInputs(force=u[2:4], rate=u[4:6], voluntary=normals, encoder=u[6:8])
        new, out = period_step(routed, model, exact, carry, u[:2], inputs)
        s_new, _ = ravel_pytree(
            (new.plant, new.fu_prev, new.x_prev, new.xd_prev, new.memory, new.voluntary, new.force_history)
        )
        return _drop_bristles(s_new), jnp.concatenate([out[0] - routed.x0, out[2]])

    u0 = jnp.zeros(2 * len(INPUTS), dtype=s0.dtype)
    (a, b), (c, d) = jax.jacfwd(period, argnums=(0, 1))(s0, u0)
    rest_out = period(s0, u0)[1] if trial.sensors.calibrated else None
    return LinearLoop(a, b, c, d, _noise_variances(trial), rest_out)


# ``linearise`` compiled whole, one program per trial structure, for callers outside ``jit``: op
# by op, its Jacobian would compile each of its ~250 operations on its own (about 9 s cold).
loop_of = jax.jit(linearise)


def respond(loop: LinearLoop, f):
    """The loop's deterministic response ``(N, 4)`` (``x - x0`` [m], ``F_h`` [N]) to the
    perturbation ``f`` ``(N, 2)`` [N] from rest, sample by sample as the simulation records it."""
    a, b, c, d = loop.a, loop.b[:, :2], loop.c, loop.d[:, :2]

    def step(s, fk):
        return a @ s + b @ fk, c @ s + d @ fk

    y = jax.lax.scan(step, jnp.zeros(a.shape[0], dtype=a.dtype), f)[1]
    return y if loop.rest is None else y + loop.rest[None, :]


def spectral_radius(loop: LinearLoop) -> float:
    """The largest modulus of ``A``'s eigenvalues (concrete): below 1 for a stable loop, per
    control period."""
    return float(np.max(np.abs(np.linalg.eigvals(np.asarray(loop.a)))))


def stationary_cov(loop: LinearLoop, inputs=None, *, doublings: int = 40):
    """The stationary covariance ``(4, 4)`` of the outputs (``x - x0`` [m], ``F_h`` [N]) driven by
    the loop's white noise inputs, all of them or those of the ``INPUTS`` groups named in
    ``inputs`` (e.g. ``("voluntary",)``: the person's force alone). The discrete Lyapunov
    equation ``S = A S A^T + B W B^T`` by doubling (``doublings`` squarings of ``A``: exact to
    round-off once ``rho(A)^(2^doublings)`` is). Pure JAX; the loop must be stable."""
    names = INPUTS[1:] if inputs is None else tuple(inputs)
    unknown = [n for n in names if n not in INPUTS[1:]]
    if unknown:
        raise ValueError(f"stationary_cov: unknown noise inputs {unknown}; the loop's are {INPUTS[1:]}")
    keep = jnp.asarray(np.repeat([n in names for n in INPUTS[1:]], 2), dtype=loop.a.dtype)
    w = loop.noise_var * keep
    bw, dw = loop.b[:, 2:] * jnp.sqrt(w)[None, :], loop.d[:, 2:] * jnp.sqrt(w)[None, :]

    def doubling(_, state):
        a, s = state
        return a @ a, s + a @ s @ a.T

    s = jax.lax.fori_loop(0, doublings, doubling, (loop.a, bw @ bw.T))[1]
    return loop.c @ s @ loop.c.T + dw @ dw.T


@jax.jit  # op by op, each operation of the linearisation would compile on its own
def drift(trial: Trial):
    """The hand's RMS drift [m] under the person's own force alone: the RMS length of ``x - x0``
    in the trial's loop without its Coulomb friction, with its ``VoluntaryForce`` and no
    perturbation (0 without one). One compiled program per trial structure; differentiable in
    the controller's gains, and ``jax.vmap`` batches trials."""
    cov = stationary_cov(linearise(trial), ("voluntary",))
    return jnp.sqrt(cov[0, 0] + cov[1, 1])
