"""Internal-model-based impedance control (paper eqs. 10-17 and 30, docs/model.md section 9.2):
``IMBIC``, kind ``"imbic"``.

The 2x2 products are written out (``matvec``) rather than left to a generic ``dot``: that
keeps the rounding identical in batched and unbatched programs and lets an unperturbed
IMBIC stay exactly at rest.
"""

from __future__ import annotations

from typing import ClassVar, NamedTuple

import equinox as eqx
import jax.numpy as jnp

from ..._checks import check_choice
from ..._pytree import Param, replace_unchecked
from ..robot import cartesian_inertia
from .base import AbstractController, gain_field, matvec
from .pd import PD_DAMPING, PD_STIFFNESS

ACCEL_ESTIMATES = ("velocity", "position")
DEFAULT_MHAT = ((0.25, 0.0), (0.0, 0.25))  # Mhat [kg] (docs/model.md section 9.2)


class IMBICMemory(NamedTuple):
    """IMBIC's memory (all ``(2,)``): ``x_k-1``, ``x_k-2`` [m], ``xd_k-1`` [m/s], ``v_k-1``
    [m/s^2] and the last command ``F_u,k-1`` [N]."""

    x_prev: jnp.ndarray
    x_prev2: jnp.ndarray
    xd_prev: jnp.ndarray
    v_prev: jnp.ndarray
    fu_prev: jnp.ndarray


class IMBIC(AbstractController):
    """Internal-model-based impedance control (paper eqs. 10-17 and 30, docs/model.md section 9.2).

    Desired robot dynamics ``M_rd xdd + B_rd xd + K_rd (x - x0) = F_Delta - F_h``, realised by
    time-delay estimation with the constant gain ``mhat``; during a movement
    ``M_rd xdd + B_rd (xd - xd_e) + K_rd (x - x_e) = F_Delta - F_h`` about the planned set point.

    Args:
        mhat: ``Mhat`` ``(2, 2)`` [kg], positive definite symmetric part (stability of time-delay
            estimation needs roughly ``0 < Mhat < 2 M_x``).
        kp, kv: ``K_p`` [N/m] and ``K_v`` [N s/m], the defaults of ``K_rd`` and ``B_rd``.
        m_rd: desired inertia ``(2, 2)`` [kg]; ``None`` (default) is the robot's Cartesian
            inertia ``M_x(q0)`` at the trial's equilibrium, resolved by ``make_trial``.
        b_rd: desired damping [N s/m]; ``None`` is ``kv``.
        k_rd: desired stiffness [N/m]; ``None`` is ``kp``.
        accel_estimate: ``"velocity"`` (``a_k-1 = (xd_k - xd_k-1) / L``, default) or
            ``"position"`` (``(x_k - 2 x_k-1 + x_k-2) / L^2``); static.

    Experiment design moves ``k_rd`` and ``b_rd``; ``design.json`` records ``mhat`` and the
    resolved desired dynamics.
    """

    kind: ClassVar[str] = "imbic"
    UNITS: ClassVar[dict] = dict(
        mhat="kg", kp="N/m", kv="N s/m", m_rd="kg", b_rd="N s/m", k_rd="N/m", accel_estimate=ACCEL_ESTIMATES
    )
    DESIGN_GAINS: ClassVar[tuple[str, str]] = ("k_rd", "b_rd")
    RECORDED: ClassVar[tuple[str, ...]] = ("mhat", "k_rd", "b_rd", "m_rd")

    mhat: Param = gain_field(DEFAULT_MHAT)
    kp: Param = gain_field(PD_STIFFNESS)
    kv: Param = gain_field(PD_DAMPING)
    m_rd: Param | None = gain_field(None)
    b_rd: Param | None = gain_field(None)
    k_rd: Param | None = gain_field(None)
    m_rd_inv: Param | None = None
    accel_estimate: str = eqx.field(static=True, default="velocity")

    def __check_init__(self):
        check_choice("accel_estimate", self.accel_estimate, ACCEL_ESTIMATES)

    def bind(self, robot, q0, x0, *, period: float) -> IMBIC:
        """Resolve the desired dynamics for the equilibrium ``q0`` (and invert ``M_rd`` once)."""
        m_rd = cartesian_inertia(q0, robot) if self.m_rd is None else jnp.asarray(self.m_rd)
        return replace_unchecked(
            self,
            m_rd=m_rd,
            b_rd=self.kv if self.b_rd is None else self.b_rd,
            k_rd=self.kp if self.k_rd is None else self.k_rd,
            m_rd_inv=jnp.linalg.inv(m_rd),
        )

    def init(self, x0) -> IMBICMemory:
        """At rest at ``x0``: ``x_-1 = x_-2 = x0``, ``xd_-1 = 0``, ``F_u,-1 = 0``,
        ``v_-1 = M_rd^-1 K_rd x0`` (an unperturbed robot then stays exactly at rest)."""
        zero = jnp.zeros_like(x0)
        return IMBICMemory(x0, x0, zero, matvec(self.m_rd_inv, matvec(self.k_rd, x0)), zero)

    def step(self, memory: IMBICMemory, x, xd, fh, f_delta, x0, period, path=None):
        if self.accel_estimate == "velocity":
            a = (xd - memory.xd_prev) / period
        else:
            a = (x - 2.0 * memory.x_prev + memory.x_prev2) / (period * period)
        minv, kd, bd = self.m_rd_inv, self.k_rd, self.b_rd
        hold = matvec(kd, x0)
        if path is not None:
            # About the moving set point: K_rd x0 becomes K_rd x_d,k + B_rd xd_e,k. Carried in v (the
            # memory's v_k is then v_k + M_rd^-1 B_rd xd_e,k), this damps xd_k - xd_e,k in u_k and
            # xd_k-1 - xd_e,k-1 in v_k with no set point kept in memory (docs/model.md).
            offset, velocity = path
            hold = matvec(kd, x0 + offset) + matvec(bd, velocity)
        v = (
            matvec(minv, (hold + f_delta) - fh)
            - (a + matvec(minv, matvec(bd, memory.xd_prev) + matvec(kd, memory.x_prev)))
            + memory.v_prev
        )
        u = v - matvec(minv, matvec(bd, xd) + matvec(kd, x))
        fu = matvec(self.mhat, u) + memory.fu_prev - matvec(self.mhat, a)
        return fu, IMBICMemory(x, memory.x_prev, xd, v, fu)
