"""MIT-MANUS robot: kinematics (forward, Jacobian, inverse) and joint-space dynamics.

Spec ``MODEL.md`` section 3. Joint coordinates ``q = (q1, q2)`` are the absolute angles
[rad] of the shoulder and elbow links from world +x; positions are world-frame [m].
All functions are single-configuration (``q`` of shape ``(2,)``); batch with ``jax.vmap``.

The scalar helpers (``endpoint_from_trig`` and friends) are the exact expressions the
plant derivative uses, so that ``x0 = fk(q0)`` and the plant's ``x`` at ``q0`` agree to
the last bit (the robot then rests exactly at its equilibrium).
"""

from __future__ import annotations

import jax.numpy as jnp

from .tables import ELBOW_LINK_LENGTH as L_E
from .tables import INERTIA_C1, INERTIA_C2, INERTIA_C3, ROBOT_BASE
from .tables import SHOULDER_LINK_LENGTH as L_S

BASE_X = float(ROBOT_BASE[0])
BASE_Y = float(ROBOT_BASE[1])


def endpoint_from_trig(c1, s1, c2, s2):
    """Handle position ``(x, y)`` [m] from ``cos/sin`` of ``q1`` and ``q2`` (scalars)."""
    return BASE_X + (L_S * c1 + L_E * c2), BASE_Y + (L_S * s1 + L_E * s2)


def jacobian_from_trig(c1, s1, c2, s2):
    """Entries ``(J11, J12, J21, J22)`` of ``J = dx/dq`` [m/rad]."""
    return -L_S * s1, -L_E * s2, L_S * c1, L_E * c2


def mass_matrix_entries(cos_d):
    """Entries ``(M11, M12, M22)`` [kg m^2] of ``M(q)``; ``cos_d = cos(q1 - q2)``."""
    return INERTIA_C1, INERTIA_C2 * cos_d, INERTIA_C3


def fk(q):
    """Forward kinematics: handle position ``x`` [m], shape ``(2,)``, from ``q`` [rad] ``(2,)``."""
    x, y = endpoint_from_trig(jnp.cos(q[0]), jnp.sin(q[0]), jnp.cos(q[1]), jnp.sin(q[1]))
    return jnp.stack([x, y])


def jacobian(q):
    """``J(q)`` [m/rad], shape ``(2, 2)``, with ``xd = J qd``."""
    j11, j12, j21, j22 = jacobian_from_trig(jnp.cos(q[0]), jnp.sin(q[0]), jnp.cos(q[1]), jnp.sin(q[1]))
    return jnp.array([[j11, j12], [j21, j22]])


def ik(x):
    """Inverse kinematics on the branch ``0 < q1 - q2 < pi``: ``q`` [rad] ``(2,)`` from ``x`` [m].

    Raises ``ValueError`` (for concrete input) when ``x`` is outside the reachable annulus.
    """
    dx = x[0] - BASE_X
    dy = x[1] - BASE_Y
    cos_d = (dx * dx + dy * dy - L_S**2 - L_E**2) / (2.0 * L_S * L_E)
    try:
        c = float(cos_d)
    except Exception:  # a tracer: cannot check here
        c = 0.0
    if not -1.0 < c < 1.0:
        raise ValueError(f"position {x} is outside the robot's workspace (cos(q1 - q2) = {c:.3f})")
    d = jnp.arccos(cos_d)  # q1 - q2 in (0, pi)
    q2 = jnp.arctan2(dy, dx) - jnp.arctan2(L_S * jnp.sin(d), L_E + L_S * jnp.cos(d))
    return jnp.stack([q2 + d, q2])


def mass_matrix(q):
    """Joint-space inertia ``M(q)`` [kg m^2], shape ``(2, 2)``, symmetric positive definite."""
    m11, m12, m22 = mass_matrix_entries(jnp.cos(q[0] - q[1]))
    return jnp.array([[m11, m12], [m12, m22]])


def velocity_torque(q, qd):
    """Centripetal torque ``h(q, qd)`` [N m], shape ``(2,)`` (there is no gravity)."""
    s = INERTIA_C2 * jnp.sin(q[0] - q[1])
    return jnp.stack([s * qd[1] ** 2, -s * qd[0] ** 2])


def kinetic_energy(q, qd):
    """Kinetic energy [J] of the linkage, ``qd^T M(q) qd / 2`` (used to check the dynamics)."""
    return 0.5 * qd @ mass_matrix(q) @ qd


def cartesian_inertia(q):
    """Apparent endpoint inertia ``M_x = J^-T M J^-1`` [kg], shape ``(2, 2)``."""
    jinv = jnp.linalg.inv(jacobian(q))
    return jinv.T @ mass_matrix(q) @ jinv


def workspace_margin(q) -> float:
    """``|det J(q)|`` [m^2]: distance from the singular (stretched or folded) postures."""
    return abs(float(jnp.linalg.det(jacobian(q))))


__all__ = [
    "cartesian_inertia",
    "fk",
    "ik",
    "jacobian",
    "kinetic_energy",
    "mass_matrix",
    "velocity_torque",
]
