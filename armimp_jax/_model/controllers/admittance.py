"""Admittance control (docs/model.md section 9.3): ``Admittance``, kind ``"admittance"``.

At each control instant ``k`` the controller reads the force the person exerts on the handle,
``F_m,k = -F_h,k`` (the transducer reads ``F_h``, the force on the hand), and integrates a
virtual mass-damper-spring over one period with ``F_m,k + F_Delta,k`` held (zero-order hold,
exact: one matrix exponential per trial, at ``bind``)::

    M_v xdd_r + B_v xd_r + K_v (x_r - x0) = F_m + F_Delta

(during a movement ``M_v xdd_r + B_v (xd_r - xd_e) + K_v (x_r - x_e) = F_m + F_Delta``, the set
point ``x_e``, ``xd_e`` sampled at ``t_k`` and held with the force).
An inner Cartesian servo then drives the robot, with its own inertia and joint friction,
towards the virtual model's new position and velocity: the command held over the period is
``F_u,k = K_p (x_r,k+1 - x_k) + K_v,servo (xd_r,k+1 - xd_k)`` (the motors apply ``J^T F_u``).
The perturbation enters through the virtual model, not as a direct robot force. As the servo
stiffens the hand follows the virtual model.
"""

from __future__ import annotations

from typing import ClassVar, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..._checks import is_concrete
from ..._pytree import Param
from ..plant import RestPlant, rest_plant
from ..robot import cartesian_inertia
from .base import AbstractController, gain_field, matvec

EYE = ((1.0, 0.0), (0.0, 1.0))
# The virtual model may sit on the unit circle (K_v = 0: a free mass-damper drifts); above this
# it grows without bound.
MARGINAL = 1e-9


def _scaled(k):
    return tuple(tuple(k * v for v in row) for row in EYE)


class AdmittanceMemory(NamedTuple):
    """The virtual model's state (both ``(2,)``): ``x_r - x0`` [m] and ``xd_r`` [m/s]."""

    offset: jnp.ndarray
    velocity: jnp.ndarray


def _mv(a, v):
    """``a @ v`` for an ``(n, m)`` matrix and ``(m,)`` vector, summed in a fixed order."""
    rows = []
    for i in range(a.shape[0]):
        acc = a[i, 0] * v[0]
        for j in range(1, a.shape[1]):
            acc = acc + a[i, j] * v[j]
        rows.append(acc)
    return jnp.stack(rows)


def discretise(m_v, b_v, k_v, period):
    """``(Phi (4, 4), Gamma (4, 2))``: the exact zero-order-hold map of the virtual model over
    ``period`` [s] on the state ``(x_r - x0, xd_r)`` with the force input ``F_m + F_Delta``."""
    minv = jnp.linalg.inv(m_v)
    z, eye = jnp.zeros((2, 2)), jnp.eye(2)
    a = jnp.block([[z, eye], [-minv @ k_v, -minv @ b_v]])
    b = jnp.concatenate([z, minv])
    generator = jnp.zeros((6, 6)).at[:4, :4].set(a).at[:4, 4:].set(b)
    hold = jax.scipy.linalg.expm(generator * period)
    return hold[:4, :4], hold[:4, 4:]


def _radius(a) -> float:
    return float(np.max(np.abs(np.linalg.eigvals(np.asarray(a)))))


def servo_radius(kp, kv, inertia, period) -> float:
    """Spectral radius per period of the servo alone on a Cartesian ``inertia`` [kg]: the
    sampled loop ``M xdd = -K_p x - K_v xd`` with the force held over each period."""
    minv = np.linalg.inv(np.asarray(inertia))
    eye, z = np.eye(2), np.zeros((2, 2))
    phi = np.block([[eye, period * eye], [z, eye]])
    gamma = np.vstack([0.5 * period**2 * minv, period * minv])
    return _radius(phi - gamma @ np.hstack([np.asarray(kp), np.asarray(kv)]))


def _expm(a):
    """``exp(a)`` by scaling and squaring a 16-term Taylor series, exact to round-off (NumPy:
    ``scipy.linalg.expm`` took 20 ms per 6x6 matrix on a loaded host, make_trial's whole budget)."""
    norm = float(np.max(np.sum(np.abs(a), axis=0)))
    squarings = max(0, int(np.ceil(np.log2(norm))) + 1) if norm > 0 else 0  # the scaled norm <= 1/2
    a = a / 2.0**squarings
    out = term = np.eye(a.shape[0])
    for k in range(1, 17):
        term = term @ a / k
        out = out + term
    for _ in range(squarings):
        out = out @ out
    return out


def _hold(a, b, period):
    """``(Phi, Gamma)``: the exact zero-order-hold map of ``s' = a s + b u`` over ``period`` (NumPy)."""
    n, m = b.shape
    generator = np.zeros((n + m, n + m))
    generator[:n, :n], generator[:n, n:] = a, b
    hold = _expm(generator * period)
    return hold[:n, :n], hold[:n, n:]


def _second_order(mass, damping, stiffness):
    """``(a, b)`` of ``mass xdd + damping xd + stiffness x = u`` on the state ``(x, xd)``."""
    minv = np.linalg.inv(mass)
    z, eye = np.zeros((2, 2)), np.eye(2)
    return np.block([[z, eye], [-minv @ stiffness, -minv @ damping]]), np.vstack([z, minv])


def coupled_radius(phi, gamma, kp, kv, plant: RestPlant, force_gain, period) -> float:
    """Spectral radius per period of the admittance loop with the arm on the handle, linear about
    rest and sampled as the simulation runs it (``plant``: ``RestPlant``; ``phi``, ``gamma``: the
    virtual model's hold; ``force_gain`` ``(2,)``: the transducer's gain the controller reads).

    State ``(x - x0, xd, the virtual model's state, F_u,k-1)``: the controller reads
    ``F_h,k = M_h xdd + B_h xd + K_h (x - x0)`` with ``F_u,k-1`` still acting, steps its
    virtual model on ``-F_h,k``, and its servo's command is held over the next period."""
    m_h, b_h, k_h = (np.asarray(getattr(plant.arm, n)) for n in ("mass", "damping", "stiffness"))
    phi_p, gamma_p = _hold(*_second_order(plant.inertia, plant.damping, k_h), period)
    share = m_h @ np.linalg.inv(plant.inertia)  # the hand's share of the acceleration a command gives
    read = np.diag(np.asarray(force_gain, dtype=float)) @ np.hstack(
        [k_h - share @ k_h, b_h - share @ plant.damping, np.zeros((2, 4)), share]
    )
    virtual = np.hstack([np.zeros((4, 4)), np.asarray(phi), np.zeros((4, 2))]) - np.asarray(gamma) @ read
    servo = np.hstack([np.asarray(kp), np.asarray(kv)])
    command = servo @ virtual - np.hstack([servo, np.zeros((2, 6))])
    plant_rows = np.hstack([phi_p, np.zeros((4, 6))]) + gamma_p @ command
    return _radius(np.vstack([plant_rows, virtual, command]))


class Admittance(AbstractController):
    """Admittance control: a virtual mass-damper-spring driven by the measured hand force and the
    perturbation, and an inner position servo (module docstring).

    Args:
        m_v: virtual mass ``M_v`` ``(2, 2)`` [kg], positive definite symmetric part.
        b_v: virtual damping ``B_v`` ``(2, 2)`` [N s/m], positive semi-definite symmetric part.
        k_v: virtual stiffness ``K_v`` ``(2, 2)`` [N/m], positive semi-definite symmetric part.
        kp: the servo's stiffness ``(2, 2)`` [N/m], positive definite symmetric part.
        kv: the servo's damping ``(2, 2)`` [N s/m], positive definite symmetric part.

    ``make_trial`` discretises the virtual model at the control period and refuses, in one line,
    a virtual model that grows (spectral radius per period above 1), a servo whose sampled
    loop on the robot's own inertia at the equilibrium is unstable, or a loop that the arm on the
    handle makes unstable (``check_loop``: a virtual mass far below the arm's). Experiment
    design moves ``k_v`` and ``b_v``.
    """

    kind: ClassVar[str] = "admittance"
    UNITS: ClassVar[dict] = dict(m_v="kg", b_v="N s/m", k_v="N/m", kp="N/m", kv="N s/m")
    DESIGN_GAINS: ClassVar[tuple[str, str]] = ("k_v", "b_v")

    m_v: Param = gain_field(_scaled(2.0))
    b_v: Param = gain_field(_scaled(10.0), semidefinite=True)
    k_v: Param = gain_field(_scaled(50.0), semidefinite=True)
    kp: Param = gain_field(_scaled(4000.0))
    kv: Param = gain_field(_scaled(60.0))
    phi: Param | None = None
    gamma: Param | None = None
    period: float | None = eqx.field(static=True, default=None)

    def bind(self, robot, q0, x0, *, period: float) -> Admittance:
        """The virtual model discretised at ``period`` [s]; its stability and the servo's on the
        robot's inertia at ``q0`` checked when the values are concrete."""
        out = self.with_gains(period=float(period))
        if is_concrete((out.phi, out.kp, out.kv, q0)):
            virtual = _radius(out.phi)
            if virtual > 1.0 + MARGINAL:
                raise ValueError(
                    f"Admittance: the virtual model (m_v, b_v, k_v) grows: spectral radius {virtual:.6f} per "
                    f"{period:g} s period, must be <= 1; make m_v positive definite and b_v, k_v >= 0"
                )
            servo = servo_radius(out.kp, out.kv, cartesian_inertia(q0, robot), period)
            if not servo < 1.0:
                raise ValueError(
                    f"Admittance: the servo (kp, kv) is unstable on the robot's inertia: spectral radius "
                    f"{servo:.6f} per {period:g} s period, must be < 1; lower kp or kv"
                )
        return out

    def check_loop(self, trial) -> None:
        """Refuse, in one line with the margin, a trial whose loop with the arm on the handle is
        unstable (``coupled_radius``; concrete values, a transducer's force: a force computed
        from the motor torques is not checked), naming the virtual mass it needs."""
        if trial.sensors.motor_force or not is_concrete(trial):
            return
        plant = rest_plant(trial.q0, trial.arm, trial.friction, trial.robot)
        gain = trial.sensors.force_gain if trial.sensors.calibrated else np.ones(2)
        radius = coupled_radius(self.phi, self.gamma, self.kp, self.kv, plant, gain, trial.period)
        if radius < 1.0:
            return
        heavier = self._stable_scale(plant, gain, trial.period)
        m_v = np.diag(np.asarray(self.m_v))
        fix = (
            "lower kp and kv"
            if heavier is None
            else f"raise m_v to about {(heavier * m_v).round(4).tolist()} kg or more ({heavier:.3g} times it)"
        )
        raise ValueError(
            f"make_trial: the admittance loop with this arm on the handle is unstable: spectral radius "
            f"{radius:.4f} per {trial.period:g} s period, must be < 1 (virtual mass diagonal "
            f"{m_v.tolist()} kg against the arm's {np.diag(np.asarray(plant.arm.mass)).tolist()} "
            f"kg); {fix}"
        )

    def _stable_scale(self, plant: RestPlant, gain, period: float) -> float | None:
        """The smallest factor on ``m_v`` (to 2%, from 1 to 1e4) at which the loop is stable, if any."""

        def stable(scale):
            phi, gamma = _hold(*_second_order(scale * np.asarray(self.m_v), self.b_v, self.k_v), period)
            return coupled_radius(phi, gamma, self.kp, self.kv, plant, gain, period) < 1.0

        grid = np.geomspace(1.0, 1e4, 25)
        k = next((i for i, scale in enumerate(grid) if stable(scale)), None)
        if k is None:
            return None
        low, high = grid[max(k - 1, 0)], grid[k]
        while high / low > 1.02:
            mid = np.sqrt(low * high)
            low, high = (low, mid) if stable(mid) else (mid, high)
        return float(high)

    def with_gains(self, **values) -> Admittance:
        """The controller with parameters replaced and its virtual model discretised again."""
        out = super().with_gains(**values)
        if out.period is None:
            return out
        phi, gamma = discretise(out.m_v, out.b_v, out.k_v, out.period)
        return super(Admittance, out).with_gains(phi=phi, gamma=gamma)

    def init(self, x0) -> AdmittanceMemory:
        """At rest: the virtual model at ``x0``, still."""
        zero = jnp.zeros_like(x0)
        return AdmittanceMemory(zero, zero)

    def step(self, memory: AdmittanceMemory, x, xd, fh, f_delta, x0, period, path=None):
        state = jnp.concatenate([memory.offset, memory.velocity])
        drive = f_delta - fh
        if path is not None:
            # The virtual spring pulls towards x_d,k and the damper damps xd_r - xd_e,k, held with
            # the force over the period: K_v (x_d,k - x0) + B_v xd_e,k more on the virtual model.
            offset, velocity = path
            drive = drive + (matvec(self.k_v, offset) + matvec(self.b_v, velocity))
        new = _mv(self.phi, state) + _mv(self.gamma, drive)
        offset, velocity = new[:2], new[2:]
        fu = matvec(self.kp, offset - (x - x0)) + matvec(self.kv, velocity - xd)
        return fu, AdmittanceMemory(offset, velocity)
