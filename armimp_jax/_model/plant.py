"""The coupled robot + arm + friction plant (docs/model.md section 5): its equations (derivative, hand
force, force sensor), not how they are integrated (``armimp_jax._solver``).

The continuous state is ``PlantState``: joint angles ``q`` [rad], rates ``qd`` [rad/s],
the friction law's states ``z`` [rad] (LuGre's bristles), and ``xi = int (x - x0) dt`` [m s] over the current
control period (for the ``"interval_mean"`` acquisition; it integrates the deviation
from ``x0`` so that a robot at rest accumulates an exact zero). Every field is a scalar,
so under ``jax.vmap`` the batch is structure-of-arrays, one ``(B,)`` array per field.

With ``x = x_h = x_r``, the hand force ``F_h = M_h xdd + B_h xd + K_h (x - x0)`` is
substituted into ``M qdd + h + tau_f = J^T (F_u - F_h)`` and solved for ``qdd``::

    (M + J^T M_h J) qdd = J^T (F_u - M_h Jd qd - B_h xd - K_h (x - x0)) - h - tau_f

A moving arm (``Arm.moving``) makes ``B_h`` and ``K_h`` functions of time and adds the force
``g(t) = K_h(t) (x_e(t) - x0) + B_h(t) xd_e(t)`` to ``F_u`` (``movement.arm_forces``): its plant
model carries ``motion`` and every evaluation takes the stage's time ``t``. A still arm's model has
``motion=None`` and runs the code it always ran.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .arm import Arm
from .friction import AbstractFriction
from .movement import MinimumJerk, MotionTerms, arm_forces, path_at, path_terms, profile_terms
from .robot import Robot, jacobian_from_trig, mass_matrix_entries


class PlantState(NamedTuple):
    """Continuous state, all scalars: ``q1, q2`` [rad], ``qd1, qd2`` [rad/s], ``z1, z2`` [rad]
    (the friction law's state; 0 for a law without one), ``xi1, xi2`` [m s]."""

    q1: jnp.ndarray
    q2: jnp.ndarray
    qd1: jnp.ndarray
    qd2: jnp.ndarray
    z1: jnp.ndarray
    z2: jnp.ndarray
    xi1: jnp.ndarray
    xi2: jnp.ndarray


class PlantModel(NamedTuple):
    """Per-trial constants of the plant derivative, all scalars (``(B,)`` under ``vmap``).

    ``x0`` [m] is the equilibrium and ``cq0 = (cos q01, sin q01, cos q02, sin q02)`` the
    trig of ``q0``: displacements ``x - x0`` are formed from trig differences, which are
    exactly zero at ``q = q0`` whatever XLA's FMA contraction does to the fused
    expressions. ``mh``, ``bh``, ``kh`` are the arm's ``(m11, m12, m21, m22)``;
    ``friction`` the friction law of each joint (``AbstractFriction.joint``: scalar fields);
    ``robot`` the robot's parameters. ``motion``: a moving arm's ``MotionTerms`` (its ``bh``
    and ``kh`` are then zero: ``arm_forces`` gives them at each stage's time), ``None`` for a still arm.
    """

    x0: tuple
    cq0: tuple
    mh: tuple
    bh: tuple
    kh: tuple
    friction: tuple
    robot: Robot
    motion: MotionTerms | None = None


def _entries(m):
    return (m[0, 0], m[0, 1], m[1, 0], m[1, 1])


def plant_model(q0, x0, arm: Arm, friction: AbstractFriction, robot: Robot) -> PlantModel:
    """Unpack trial parameters into the scalars the inner loop uses (hoisted out of it)."""
    cq0 = (jnp.cos(q0[0]), jnp.sin(q0[0]), jnp.cos(q0[1]), jnp.sin(q0[1]))
    if arm.moving:
        zero = (jnp.zeros_like(x0[0]),) * 4
        path = path_terms(arm.endpoint) if isinstance(arm.endpoint, MinimumJerk) else None
        motion = MotionTerms(profile_terms(arm.damping), profile_terms(arm.stiffness), path)
        joints = (friction.joint(0), friction.joint(1))
        return PlantModel((x0[0], x0[1]), cq0, _entries(arm.mass), zero, zero, joints, robot, motion)
    return PlantModel(
        (x0[0], x0[1]),
        cq0,
        _entries(arm.mass),
        _entries(arm.damping),
        _entries(arm.stiffness),
        (friction.joint(0), friction.joint(1)),
        robot,
    )


class RestPlant(NamedTuple):
    """The coupled plant linearised at rest, in Cartesian coordinates about ``x0`` (NumPy ``(2, 2)``
    each): ``inertia xdd + damping xd + arm.stiffness (x - x0) = F_u``, where ``inertia`` [kg] is the
    robot's apparent inertia ``M_x(q0)`` plus the arm's mass and ``damping`` [N s/m] the arm's plus
    the joints' viscous friction ``J^-T C J^-1``; the hand force is ``F_h = M_h xdd + B_h xd +
    K_h (x - x0)`` (``arm``). Coulomb friction is left out, as in the linearisation behind ``crlb``."""

    inertia: np.ndarray
    damping: np.ndarray
    arm: Arm


def rest_plant(q0, arm: Arm, friction: AbstractFriction, robot: Robot) -> RestPlant:
    """``RestPlant`` at the equilibrium ``q0`` [rad] (concrete values; NumPy throughout: make_trial
    calls it, and op by op JAX would cost milliseconds)."""
    q = np.asarray(q0, dtype=float)
    robot = jax.tree.map(np.asarray, robot)
    jinv = np.linalg.inv(
        np.reshape(jacobian_from_trig(robot, np.cos(q[0]), np.sin(q[0]), np.cos(q[1]), np.sin(q[1])), (2, 2))
    )
    m11, m12, m22 = mass_matrix_entries(robot, np.cos(q[0] - q[1]))
    joints = jinv.T @ np.array([[m11, m12], [m12, m22]]) @ jinv  # M_x(q0), as robot.cartesian_inertia
    viscous = np.diag([float(np.asarray(friction.joint(i).viscous_coefficient())) for i in range(2)])
    mass, damping = (np.asarray(a, dtype=float) for a in (arm.mass, arm.damping))
    return RestPlant(joints + mass, damping + jinv.T @ viscous @ jinv, arm)


def rest_state(q0) -> PlantState:
    """The robot at rest at ``q0`` with relaxed bristles."""
    zero = jnp.zeros_like(q0[0])
    return PlantState(q0[0], q0[1], zero, zero, zero, zero, zero, zero)


class Trig(NamedTuple):
    """``cos q1, sin q1, cos q2, sin q2`` of a state (the only transcendentals of the robot)."""

    c1: jnp.ndarray
    s1: jnp.ndarray
    c2: jnp.ndarray
    s2: jnp.ndarray


def trig_of(s: PlantState) -> Trig:
    """``Trig`` of a state's joint angles."""
    return Trig(jnp.cos(s.q1), jnp.sin(s.q1), jnp.cos(s.q2), jnp.sin(s.q2))


def trig_of_angles(q) -> Trig:
    """``Trig`` of the joint angles ``q = (q1, q2)`` [rad]."""
    return Trig(jnp.cos(q[0]), jnp.sin(q[0]), jnp.cos(q[1]), jnp.sin(q[1]))


def displacement(t: Trig, model: PlantModel):
    """``x - x0`` [m] from the trig of the angles, as trig differences against ``q0``'s:
    exactly 0 at ``q = q0``."""
    c10, s10, c20, s20 = model.cq0
    ls, le = model.robot.shoulder_link, model.robot.elbow_link
    return ls * (t.c1 - c10) + le * (t.c2 - c20), ls * (t.s1 - s10) + le * (t.s2 - s20)


def coupled_inertia(model: PlantModel, j, m):
    """Entries ``(a11, a12, a21, a22)`` [kg m^2] of ``A = M + J^T M_h J`` from the Jacobian
    entries ``j`` and the robot's ``m = (M11, M12, M22)``; not symmetric (``M_h`` is not)."""
    j11, j12, j21, j22 = j
    m11, m12, m22 = m
    mh11, mh12, mh21, mh22 = model.mh
    p11 = mh11 * j11 + mh12 * j21
    p12 = mh11 * j12 + mh12 * j22
    p21 = mh21 * j11 + mh22 * j21
    p22 = mh21 * j12 + mh22 * j22
    return (
        m11 + (j11 * p11 + j21 * p21),
        m12 + (j11 * p12 + j21 * p22),
        m12 + (j12 * p11 + j22 * p21),
        m22 + (j12 * p12 + j22 * p22),
    )


class Dynamics(NamedTuple):
    """What one evaluation of the plant gives: the state's time ``derivative``, the hand's
    ``displacement`` ``x - x0`` [m] and ``velocity`` [m/s], ``hand_force_rest`` (the hand
    force without its ``M_h J qdd`` part) [N] and ``jqdd`` (``J qdd``) [m/s^2], each a pair."""

    derivative: PlantState
    displacement: tuple
    velocity: tuple
    hand_force_rest: tuple
    jqdd: tuple


def _unshared(group, *values):
    return values


def moving_arm(model: PlantModel, t):
    """``(B_h, K_h, g)`` of a moving arm's model at time ``t`` [s] (``movement.arm_forces``);
    a one-line error when the caller gave no time."""
    if t is None:
        raise ValueError("the plant of a moving arm needs the time t [s] of each evaluation")
    return arm_forces(model.motion, t)


def plant_dynamics(
    s: PlantState, fu, model: PlantModel, *, trig: Trig | None = None, share=_unshared, t=None
) -> Dynamics:
    """The plant's equations at state ``s`` under the Cartesian command ``fu`` [N] ``(2,)``.

    ``trig`` (optional) supplies ``cos/sin`` of ``q``; by default they are evaluated.
    ``share(group, *values) -> values`` (default: identity) lets an integrator mark the 2x2
    solve's matrix (group ``"a"``) and right-hand side (``"b"``); it must return the values
    unchanged to round-off. ``t`` [s]: the time, which a moving arm's model needs."""
    c1, s1, c2, s2 = trig_of(s) if trig is None else trig
    # Angle-difference identities instead of cos/sin(q1 - q2): two fewer transcendentals
    # per evaluation (they dominate the cost on CPU), error ~1e-16.
    cos_d = c1 * c2 + s1 * s2
    sin_d = s1 * c2 - c1 * s2
    ex, ey = displacement(Trig(c1, s1, c2, s2), model)
    L_S, L_E = model.robot.shoulder_link, model.robot.elbow_link
    j11, j12, j21, j22 = jacobian_from_trig(model.robot, c1, s1, c2, s2)
    m11, m12, m22 = mass_matrix_entries(model.robot, cos_d)
    mh11, mh12, mh21, mh22 = model.mh
    bh, kh, g = (model.bh, model.kh, None) if model.motion is None else moving_arm(model, t)
    bh11, bh12, bh21, bh22 = bh
    kh11, kh12, kh21, kh22 = kh
    qd1sq, qd2sq = s.qd1 * s.qd1, s.qd2 * s.qd2

    xd = j11 * s.qd1 + j12 * s.qd2
    yd = j21 * s.qd1 + j22 * s.qd2
    jdqd_x = -L_S * c1 * qd1sq - L_E * c2 * qd2sq  # Jd qd
    jdqd_y = -L_S * s1 * qd1sq - L_E * s2 * qd2sq

    # Hand force without its J qdd part: M_h Jd qd + B_h xd + K_h (x - x0).
    f0x = (mh11 * jdqd_x + mh12 * jdqd_y) + (bh11 * xd + bh12 * yd) + (kh11 * ex + kh12 * ey)
    f0y = (mh21 * jdqd_x + mh22 * jdqd_y) + (bh21 * xd + bh22 * yd) + (kh21 * ex + kh22 * ey)
    if g is not None:  # the moving equilibrium's pull: F_h = ... + B_h (xd - xd_e) + K_h (x - x_e)
        f0x, f0y = f0x - g[0], f0y - g[1]
    rx, ry = fu[0] - f0x, fu[1] - f0y

    tau_f1, zd1 = model.friction[0].torque_and_rate(s.qd1, s.z1)
    tau_f2, zd2 = model.friction[1].torque_and_rate(s.qd2, s.z2)
    hc = model.robot.inertia[1] * sin_d
    b1 = (j11 * rx + j21 * ry) - hc * qd2sq - tau_f1
    b2 = (j12 * rx + j22 * ry) + hc * qd1sq - tau_f2
    b1, b2 = share("b", b1, b2)

    a11, a12, a21, a22 = share("a", *coupled_inertia(model, (j11, j12, j21, j22), (m11, m12, m22)))
    det = a11 * a22 - a12 * a21
    qdd1 = (a22 * b1 - a12 * b2) / det
    qdd2 = (a11 * b2 - a21 * b1) / det
    deriv = PlantState(s.qd1, s.qd2, qdd1, qdd2, zd1, zd2, ex, ey)
    jqdd = (j11 * qdd1 + j12 * qdd2, j21 * qdd1 + j22 * qdd2)
    return Dynamics(deriv, (ex, ey), (xd, yd), (f0x, f0y), jqdd)


def plant_derivative(s: PlantState, fu, model: PlantModel, t=None) -> PlantState:
    """Time derivative of the state under the Cartesian command ``fu`` [N] ``(2,)`` (at time ``t``
    [s], which a moving arm needs)."""
    return plant_dynamics(s, fu, model, t=t).derivative


def measure(s: PlantState, fu, model: PlantModel, t=None):
    """Ideal sensors at state ``s`` while command ``fu`` acts: ``(x, xd, F_h)``, each ``(2,)``.

    ``F_h`` [N] is the transducer force (the force on the hand), from the same
    acceleration the plant integrates; ``t`` [s], the time, which a moving arm needs.
    """
    _, (ex, ey), (xd, yd), (f0x, f0y), (ax, ay) = plant_dynamics(s, fu, model, t=t)
    mh11, mh12, mh21, mh22 = model.mh
    fh = jnp.stack([(mh11 * ax + mh12 * ay) + f0x, (mh21 * ax + mh22 * ay) + f0y])
    return jnp.stack([model.x0[0] + ex, model.x0[1] + ey]), jnp.stack([xd, yd]), fh


def near_path(model: PlantModel, s: PlantState, t, distance):
    """Whether the hand at state ``s`` is within ``distance`` [m] of a moving arm's planned path at
    time ``t`` [s] (the simulation's range check during a reach)."""
    ex, ey = displacement(trig_of(s), model)
    (ox, oy), _ = path_at(model.motion.path, t)
    return (ex - ox) ** 2 + (ey - oy) ** 2 < distance * distance
