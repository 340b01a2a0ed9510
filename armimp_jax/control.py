"""Controllers (spec section 7): PD and IMBIC, as pure per-sample functions with explicit memory.

Both act once per control period on the instantaneous samples ``x_k`` [m], ``xd_k``
[m/s], ``F_h,k`` [N] and the perturbation ``F_Delta,k`` [N], and return the Cartesian
command ``F_u,k`` [N] held over the next period. Vectors are ``(2,)``; batch with
``jax.vmap``. The 2x2 products are written out (``matvec``) rather than left to a
generic ``dot``: that keeps the rounding identical in batched and unbatched programs
and lets an unperturbed IMBIC stay exactly at rest (section 13 of the spec).
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp

from .robot import cartesian_inertia
from .tables import PD_DAMPING, PD_STIFFNESS

CONTROLLERS = ("pd", "imbic")
ACCEL_ESTIMATES = ("velocity", "position")


def matvec(a, v):
    """``a @ v`` for a ``(2, 2)`` matrix and a ``(2,)`` vector, with a fixed summation order."""
    return jnp.stack([a[0, 0] * v[0] + a[0, 1] * v[1], a[1, 0] * v[0] + a[1, 1] * v[1]])


class ControllerGains(NamedTuple):
    """Gains, each ``(2, 2)`` float64. ``kp`` [N/m], ``kv`` [N s/m]; IMBIC: ``m_rd`` [kg],
    its inverse, and ``mhat`` [kg]. IMBIC's desired dynamics use ``B_rd = kv``, ``K_rd = kp``."""

    kp: jnp.ndarray
    kv: jnp.ndarray
    m_rd: jnp.ndarray
    m_rd_inv: jnp.ndarray
    mhat: jnp.ndarray


class ControllerMemory(NamedTuple):
    """What a controller remembers between samples (all ``(2,)``): ``x_k-1``, ``x_k-2`` [m],
    ``xd_k-1`` [m/s], IMBIC's ``v_k-1`` [m/s^2] and the last command ``F_u,k-1`` [N]."""

    x_prev: jnp.ndarray
    x_prev2: jnp.ndarray
    xd_prev: jnp.ndarray
    v_prev: jnp.ndarray
    fu_prev: jnp.ndarray


def controller_gains(q0, mhat) -> ControllerGains:
    """Gains for the equilibrium ``q0``: ``M_rd = M_x(q0)``, the paper's ``K_p``, ``K_v``, and ``mhat``."""
    m_rd = cartesian_inertia(q0)
    return ControllerGains(
        kp=jnp.asarray(PD_STIFFNESS),
        kv=jnp.asarray(PD_DAMPING),
        m_rd=m_rd,
        m_rd_inv=jnp.linalg.inv(m_rd),
        mhat=mhat,
    )


def controller_init(x0, gains: ControllerGains) -> ControllerMemory:
    """Memory of a robot at rest at ``x0``: ``x_-1 = x_-2 = x0``, ``xd_-1 = 0``, ``F_u,-1 = 0``,
    ``v_-1 = M_rd^-1 K_rd x0`` (so that IMBIC keeps an unperturbed robot exactly at rest)."""
    zero = jnp.zeros_like(x0)
    return ControllerMemory(x0, x0, zero, matvec(gains.m_rd_inv, matvec(gains.kp, x0)), zero)


def pd_command(x, xd, f_delta, x0, gains: ControllerGains):
    """PD (paper eq. 5): ``F_u = F_Delta - K_p (x - x0) - K_v xd``."""
    return f_delta - matvec(gains.kp, x - x0) - matvec(gains.kv, xd)


def imbic_command(x, xd, f_delta, fh, memory: ControllerMemory, x0, gains: ControllerGains, *, period, accel_estimate):
    """IMBIC (paper eq. 30, spec 7.2). Returns ``(F_u,k, v_k)``.

    ``accel_estimate="velocity"``: ``a_k-1 = (xd_k - xd_k-1) / L``;
    ``"position"``: ``(x_k - 2 x_k-1 + x_k-2) / L^2``.
    """
    if accel_estimate == "velocity":
        a = (xd - memory.xd_prev) / period
    else:
        a = (x - 2.0 * memory.x_prev + memory.x_prev2) / (period * period)
    minv, kd, bd = gains.m_rd_inv, gains.kp, gains.kv
    v = (
        matvec(minv, (matvec(kd, x0) + f_delta) - fh)
        - (a + matvec(minv, matvec(bd, memory.xd_prev) + matvec(kd, memory.x_prev)))
        + memory.v_prev
    )
    u = v - matvec(minv, matvec(bd, xd) + matvec(kd, x))
    fu = matvec(gains.mhat, u) + memory.fu_prev - matvec(gains.mhat, a)
    return fu, v


def controller_step(controller, x, xd, f_delta, fh, memory: ControllerMemory, x0, gains, *, period, accel_estimate):
    """One sample of ``controller`` ("pd" or "imbic", static). Returns ``(F_u,k, new memory)``."""
    if controller == "pd":
        fu, v = pd_command(x, xd, f_delta, x0, gains), memory.v_prev
    else:
        fu, v = imbic_command(x, xd, f_delta, fh, memory, x0, gains, period=period, accel_estimate=accel_estimate)
    return fu, ControllerMemory(x, memory.x_prev, xd, v, fu)
