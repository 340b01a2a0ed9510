"""The robot: a planar five-bar (parallelogram) linkage with direct-drive motors at its base.

docs/model.md section 2. ``Robot`` holds the link lengths, the three inertia
constants and the base position; ``MIT_MANUS`` is the default. Joint coordinates
``q = (q1, q2)`` are the absolute angles [rad] of the shoulder and elbow links from
world +x; positions are world-frame [m]. Functions are single-configuration (``q`` of
shape ``(2,)``); batch with ``jax.vmap``.

The scalar helpers (``endpoint_from_trig`` and friends) are the exact expressions the
plant derivative uses, so that ``x0 = fk(q0)`` and the plant's ``x`` at ``q0`` agree to
the last bit (the robot then rests exactly at its equilibrium).
"""

from __future__ import annotations

import math

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._checks import as_param, check_range, is_concrete
from .._pytree import Param, params
from .arm import arm_endpoint

# MIT-MANUS / InMotion2 (docs/model.md section 15.1: public control code, constant regression terms).
MIT_MANUS_SHOULDER_LINK = 0.4064  # L_s [m]
MIT_MANUS_ELBOW_LINK = 0.51435  # L_e [m]
MIT_MANUS_INERTIA = (0.391162880843, 0.226826719396, 0.227888039765)  # c1, c2, c3 [kg m^2]
# The base sits 0.65 m behind the handle at the paper's arm location 1 (docs/model.md sections 2 and 15.1).
MIT_MANUS_BASE = arm_endpoint(math.radians(62.708), math.radians(77.260)) + np.array([0.0, 0.65])

# An endpoint is refused when |sin(q1 - q2)| is below this: |det J| = L_s L_e |sin(q1 - q2)|,
# and near the stretched or folded posture the Cartesian inertia and the controllers blow up
# (the paper's four locations have |sin(q1 - q2)| >= 0.77).
MIN_ELBOW_SINE = 0.1


@params
class Robot:
    """Parameters of the five-bar robot (an immutable pytree of float64 leaves).

    Args:
        shoulder_link: ``L_s`` [m], length of the link driven by motor 1.
        elbow_link: ``L_e`` [m], length of the link driven by motor 2.
        inertia: ``(c1, c2, c3)`` [kg m^2]: ``M(q) = [[c1, c2 cos(q1 - q2)], [c2 cos(q1 - q2), c3]]``.
        base: ``(2,)`` [m], motor axis in the world frame (origin at the human shoulder).

    Defaults are MIT-MANUS (``MIT_MANUS``). Raises ``ValueError`` for non-positive
    lengths, an inertia matrix that is not positive definite, or wrong shapes.
    """

    shoulder_link: Param = MIT_MANUS_SHOULDER_LINK
    elbow_link: Param = MIT_MANUS_ELBOW_LINK
    inertia: Param = MIT_MANUS_INERTIA
    base: Param = tuple(MIT_MANUS_BASE)

    def __post_init__(self):
        w = "Robot"
        set_ = object.__setattr__
        set_(self, "shoulder_link", as_param("shoulder_link [m]", self.shoulder_link, (), where=w))
        set_(self, "elbow_link", as_param("elbow_link [m]", self.elbow_link, (), where=w))
        set_(self, "inertia", as_param("inertia (c1, c2, c3) [kg m^2]", self.inertia, (3,), where=w))
        set_(self, "base", as_param("base [m]", self.base, (2,), where=w))
        for name in ("shoulder_link", "elbow_link"):
            set_(self, name, check_range(name, getattr(self, name), where=w, minimum=0.0, exclusive=True, unit=" m"))
        if not is_concrete(self.inertia):
            c1, c2, c3 = self.inertia[0], self.inertia[1], self.inertia[2]
            bad = (c1 <= 0) | (c3 <= 0) | (c1 * c3 <= c2 * c2)
            message = "Robot: inertia (c1, c2, c3) must give a positive definite M(q) (c1 > 0, c3 > 0, c1 c3 > c2^2)"
            set_(self, "inertia", eqx.error_if(self.inertia, bad, message))
        else:
            c1, c2, c3 = np.asarray(self.inertia)
            if not (c1 > 0 and c3 > 0 and c1 * c3 > c2 * c2):
                raise ValueError(
                    f"Robot: inertia (c1, c2, c3) must give a positive definite M(q) for every posture "
                    f"(c1 > 0, c3 > 0, c1 c3 > c2^2), got {[float(c1), float(c2), float(c3)]} kg m^2"
                )


MIT_MANUS = Robot()


def endpoint_from_trig(robot: Robot, c1, s1, c2, s2):
    """Handle position ``(x, y)`` [m] from ``cos/sin`` of ``q1`` and ``q2`` (scalars)."""
    ls, le = robot.shoulder_link, robot.elbow_link
    return robot.base[0] + (ls * c1 + le * c2), robot.base[1] + (ls * s1 + le * s2)


def jacobian_from_trig(robot: Robot, c1, s1, c2, s2):
    """Entries ``(J11, J12, J21, J22)`` of ``J = dx/dq`` [m/rad]."""
    ls, le = robot.shoulder_link, robot.elbow_link
    return -ls * s1, -le * s2, ls * c1, le * c2


def mass_matrix_entries(robot: Robot, cos_d):
    """Entries ``(M11, M12, M22)`` [kg m^2] of ``M(q)``; ``cos_d = cos(q1 - q2)``."""
    return robot.inertia[0], robot.inertia[1] * cos_d, robot.inertia[2]


def fk(q, robot: Robot = MIT_MANUS):
    """Forward kinematics: handle position ``x`` [m], shape ``(2,)``, from ``q`` [rad] ``(2,)``."""
    x, y = endpoint_from_trig(robot, jnp.cos(q[0]), jnp.sin(q[0]), jnp.cos(q[1]), jnp.sin(q[1]))
    return jnp.stack([x, y])


def jacobian(q, robot: Robot = MIT_MANUS):
    """``J(q)`` [m/rad], shape ``(2, 2)``, with ``xd = J qd``."""
    j11, j12, j21, j22 = jacobian_from_trig(robot, jnp.cos(q[0]), jnp.sin(q[0]), jnp.cos(q[1]), jnp.sin(q[1]))
    return jnp.array([[j11, j12], [j21, j22]])


def ik(x, robot: Robot = MIT_MANUS):
    """Inverse kinematics on the branch ``0 < q1 - q2 < pi``: ``q`` [rad] ``(2,)`` from ``x`` [m].

    Raises ``ValueError`` (for concrete input) when ``x`` is outside the reachable annulus
    or so close to its edge that ``|sin(q1 - q2)| < MIN_ELBOW_SINE`` (near-singular Jacobian).
    """
    ls, le = robot.shoulder_link, robot.elbow_link
    dx = x[0] - robot.base[0]
    dy = x[1] - robot.base[1]
    cos_d = (dx * dx + dy * dy - ls**2 - le**2) / (2.0 * ls * le)
    if is_concrete(cos_d):
        c = float(cos_d)
        if not -1.0 < c < 1.0:
            raise ValueError(
                f"endpoint {np.asarray(x).tolist()} m is outside the robot's workspace (needs cos(q1 - q2) in "
                f"(-1, 1), got {c:.3f}; reachable: {abs(float(ls) - float(le)):.3f} to "
                f"{float(ls) + float(le):.3f} m from the base {np.asarray(robot.base).tolist()})"
            )
        if math.sqrt(1.0 - c * c) < MIN_ELBOW_SINE:
            raise ValueError(
                f"endpoint {np.asarray(x).tolist()} m is too close to a singular posture of the robot "
                f"(|sin(q1 - q2)| = {math.sqrt(1.0 - c * c):.3f}, allowed >= {MIN_ELBOW_SINE}): the Jacobian is "
                "near singular there"
            )
    d = jnp.arccos(cos_d)  # q1 - q2 in (0, pi)
    q2 = jnp.arctan2(dy, dx) - jnp.arctan2(ls * jnp.sin(d), le + ls * jnp.cos(d))
    return jnp.stack([q2 + d, q2])


def mass_matrix(q, robot: Robot = MIT_MANUS):
    """Joint-space inertia ``M(q)`` [kg m^2], shape ``(2, 2)``, symmetric positive definite."""
    m11, m12, m22 = mass_matrix_entries(robot, jnp.cos(q[0] - q[1]))
    return jnp.array([[m11, m12], [m12, m22]])


def velocity_torque(q, qd, robot: Robot = MIT_MANUS):
    """Centripetal torque ``h(q, qd)`` [N m], shape ``(2,)`` (there is no gravity)."""
    s = robot.inertia[1] * jnp.sin(q[0] - q[1])
    return jnp.stack([s * qd[1] ** 2, -s * qd[0] ** 2])


def kinetic_energy(q, qd, robot: Robot = MIT_MANUS):
    """Kinetic energy [J] of the linkage, ``qd^T M(q) qd / 2``."""
    return 0.5 * qd @ mass_matrix(q, robot) @ qd


def cartesian_inertia(q, robot: Robot = MIT_MANUS):
    """Apparent endpoint inertia ``M_x = J^-T M J^-1`` [kg], shape ``(2, 2)``."""
    jinv = jnp.linalg.inv(jacobian(q, robot))
    return jinv.T @ mass_matrix(q, robot) @ jinv


def workspace_margin(q, robot: Robot = MIT_MANUS) -> float:
    """``|det J(q)|`` [m^2]: distance from the singular (stretched or folded) postures."""
    return abs(float(jnp.linalg.det(jacobian(q, robot))))


def check_reach(start, end, robot: Robot = MIT_MANUS, *, where: str = "make_trial") -> None:
    """Refuse, in one line, a straight reach from ``start`` to ``end`` [m] (concrete) that leaves the
    robot's workspace or passes near a singular posture on its way (``ik``'s rule at every point of
    it; exact: ``cos(q1 - q2)`` grows with the distance from the base, whose extremes on a segment
    lie at its ends or at the base's projection on it)."""
    base = np.asarray(robot.base, dtype=float)
    a, b = np.asarray(start, dtype=float), np.asarray(end, dtype=float)
    d = b - a
    s = 0.0 if not np.any(d) else float(np.clip(-((a - base) @ d) / (d @ d), 0.0, 1.0))
    ls, le = float(robot.shoulder_link), float(robot.elbow_link)
    for point in (a, b, a + s * d):
        r = point - base
        c = (float(r @ r) - ls * ls - le * le) / (2.0 * ls * le)
        if -1.0 < c < 1.0 and math.sqrt(1.0 - c * c) >= MIN_ELBOW_SINE:
            continue
        why = "outside the robot's workspace" if not -1.0 < c < 1.0 else "too close to a singular posture"
        raise ValueError(
            f"{where}: the reach from {a.round(4).tolist()} to {b.round(4).tolist()} m passes {why} at "
            f"{point.round(4).tolist()} m (reachable with |sin(q1 - q2)| >= {MIN_ELBOW_SINE}: about "
            f"{abs(ls - le):.3f} to {ls + le:.3f} m from the base {base.round(4).tolist()}); shorten or move the reach"
        )
