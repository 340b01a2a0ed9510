"""The closed loop linearised about its rest: one control period as a discrete-time state space.

Near rest the whole sampled loop (plant, integrator, sensors, controller, acquisition and the
person's force filter) is one linear map per control period,

    s_k+1 = A s_k + B u_k,        y_k = C s_k + D u_k,

obtained by forward-mode differentiation of the simulator's own period step
(``_simulate.period_step``) at the rest state, so it is exactly the simulation's loop to
first order, with its zero-order holds, its instant or interval-mean samples and its
integrator. ``s`` is every float of the loop's carry; the inputs ``u`` are ``INPUTS``: the
perturbation ``F_Delta`` [N], then the noise of one period: force-sensor noise [N], joint
rate noise [rad/s], the encoders' quantisation error as an angle [rad] (white, variance
``D^2 / 12``: the reading's error over a motion of many counts) and the white driver of the
person's force (unitless). The outputs ``y`` are the recorded ``x - x0`` [m] and ``F_h`` [N].

What it gives, all pure JAX and differentiable in every float of the trial (gains, arm,
robot, noise levels) and in the perturbation: the deterministic response to ``F_Delta``
from rest (``respond``), the noise's spectral matrix at the DFT bins of a record
(``noise_spectrum``) and the loop's stability (``spectral_radius``). Joint friction is
linearised as it stands at rest, where LuGre's bristles are a stiff spring (stuck joints):
a friction-free reference is ``without_friction(trial)``.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
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
# Impulse-response length behind ``noise_spectrum``, at least (samples): the loop's slowest
# decay (the person's force filter, IMBIC's desired dynamics) is far within it.
IMPULSE_SAMPLES = 1 << 15


class LinearLoop(NamedTuple):
    """The loop linearised about rest (a pytree of arrays; ``jax.vmap`` stacks them).

    ``a`` ``(n, n)``, ``b`` ``(n, 10)``, ``c`` ``(4, n)``, ``d`` ``(4, 10)``: the state space
    above, inputs in the order of ``INPUTS`` (two each), outputs ``OUTPUTS``. ``noise_var``
    ``(8,)``: the per-sample variance of each noise input (``u[2:]``): ``sigma_F^2`` [N^2],
    ``sigma_v^2`` [rad^2/s^2], ``D^2 / 12`` [rad^2] (0 without encoders), 1 (0 without the
    person's force)."""

    a: jnp.ndarray
    b: jnp.ndarray
    c: jnp.ndarray
    d: jnp.ndarray
    noise_var: jnp.ndarray


def without_friction(trial: Trial) -> Trial:
    """``trial`` without its Coulomb and Stribeck friction (``tau_c = tau_s = 0``: no bristles),
    its viscous friction kept (linear): the loop IMBIC promises to leave."""
    fr = trial.friction
    return replace_unchecked(
        trial, friction=replace_unchecked(fr, tau_c=jnp.zeros_like(fr.tau_c), tau_s=jnp.zeros_like(fr.tau_s))
    )


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
    """The trial's loop without joint friction, linearised about rest (see the module docstring).

    Single-trial and traceable: ``jax.vmap`` over stacked trials, ``jax.grad`` / ``jax.jacfwd``
    through any float of ``trial``.
    """
    routed = replace_unchecked(without_friction(trial), sensors=_ROUTED)
    model = plant_model(routed.q0, routed.x0, routed.arm, routed.friction, routed.robot)
    rest = simulate_init(routed)
    rest = rest._replace(k=jnp.asarray(1, dtype=jnp.int32))  # past the person's force's start
    exact = _ExactNumerics(_ExactPlant(rest.plant))
    floats = (rest.plant, rest.fu_prev, rest.x_prev, rest.xd_prev, rest.memory, rest.voluntary)
    s0, unravel = ravel_pytree(floats)
    s0 = _drop_bristles(s0)
    with_voluntary = trial.voluntary is not None

    def period(s, u):
        plant, fu_prev, x_prev, xd_prev, memory, voluntary = unravel(_with_bristles(s))
        carry = rest._replace(
            plant=plant, fu_prev=fu_prev, x_prev=x_prev, xd_prev=xd_prev, memory=memory, voluntary=voluntary
        )
        normals = jnp.concatenate([u[8:10][None], jnp.zeros((2, 2), u.dtype)]) if with_voluntary else None
        inputs = PeriodInputs(force=u[2:4], rate=u[4:6], voluntary=normals, encoder=u[6:8])
        new, out = period_step(routed, model, exact, carry, u[:2], inputs)
        s_new, _ = ravel_pytree((new.plant, new.fu_prev, new.x_prev, new.xd_prev, new.memory, new.voluntary))
        return _drop_bristles(s_new), jnp.concatenate([out[0] - routed.x0, out[2]])

    u0 = jnp.zeros(2 * len(INPUTS), dtype=s0.dtype)
    (a, b), (c, d) = jax.jacfwd(period, argnums=(0, 1))(s0, u0)
    return LinearLoop(a, b, c, d, _noise_variances(trial))


def respond(loop: LinearLoop, f):
    """The loop's deterministic response ``(N, 4)`` (``x - x0`` [m], ``F_h`` [N]) to the
    perturbation ``f`` ``(N, 2)`` [N] from rest, sample by sample as the simulation records it."""
    a, b, c, d = loop.a, loop.b[:, :2], loop.c, loop.d[:, :2]

    def step(s, fk):
        return a @ s + b @ fk, c @ s + d @ fk

    return jax.lax.scan(step, jnp.zeros(a.shape[0], dtype=a.dtype), f)[1]


def _impulse(loop: LinearLoop, length: int):
    """Impulse response of the outputs to the noise inputs, ``(length, 4, 8)``."""
    a, b, c, d = loop.a, loop.b[:, 2:], loop.c, loop.d[:, 2:]

    def step(x, _):
        return a @ x, c @ x

    tail = jax.lax.scan(step, b, None, length=length - 1)[1]
    return jnp.concatenate([d[None], tail])


def noise_spectrum(loop: LinearLoop, n: int):
    """The noise's spectral matrix ``S_k`` ``(n // 2 - 1, 4, 4)`` (complex, Hermitian) at the
    DFT bins ``k = 1 .. n/2 - 1`` of an ``n``-sample record: ``N S_k = E[V_k V_k^H]`` for the
    DFT ``V_k`` of the outputs' stationary noise (units: m^2, m N, N^2 per sample).

    From the impulse response over a multiple of ``n`` samples (at least
    ``IMPULSE_SAMPLES``), so the bins are exact once the loop's response has decayed
    within it; a loop that has not (unstable, or barely damped) gives a meaningless
    spectrum: check ``spectral_radius`` first."""
    length = n * max(1, -(-IMPULSE_SAMPLES // n))
    h = _impulse(loop, length)
    g = jnp.fft.fft(h, axis=0)[(length // n) * jnp.arange(1, n // 2)]  # (K, 4, 8)
    scaled = g * loop.noise_var[None, None, :]
    return jnp.einsum("kin,kjn->kij", scaled, jnp.conj(g))


def spectral_radius(loop: LinearLoop):
    """The largest modulus of ``A``'s eigenvalues: below 1 for a stable loop (per period)."""
    return jnp.max(jnp.abs(jnp.linalg.eigvals(jax.lax.stop_gradient(loop.a))))


def information_from(dy, spectrum):
    """The Whittle information ``sum_k 2 Re[dY_k^H (N S_k)^-1 dY_k]`` ``(p, p)`` of the output
    derivatives ``dy`` ``(N, 4, p)`` (the deterministic response's derivative in each of ``p``
    parameters) against the noise ``spectrum`` ``(N // 2 - 1, 4, 4)`` of ``noise_spectrum``."""
    n = dy.shape[0]
    dY = jnp.fft.rfft(dy, axis=0)[1 : n // 2]  # (K, 4, p)
    w_dY = jnp.linalg.solve(spectrum, dY)
    return 2.0 * jnp.real(jnp.einsum("kip,kiq->pq", jnp.conj(dY), w_dY)) / n
