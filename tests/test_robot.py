"""Robot kinematics and the coupled dynamics against independent computations: the spec's
kinematics and Lagrangian (docs/model.md section 2; the paper's MIT-MANUS constants) written
out in this file, not read from ``armimp_jax._model.robot``."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from armimp_jax import paper
from armimp_jax._model import robot
from armimp_jax._model.plant import PlantState, plant_derivative, plant_model
from armimp_jax._model.robot import MIT_MANUS_BASE as ROBOT_BASE
from armimp_jax.paper import location_endpoint

# MIT-MANUS (docs/model.md section 2): link lengths [m], inertia constants [kg m^2], the motor axis [m]
L_S, L_E = 0.4064, 0.51435
C1, C2, C3 = 0.391162880843, 0.226826719396, 0.227888039765
L_U, L_F = 0.21, 0.32  # the arm's upper arm and forearm plus hand [m], which place location 1


def arm_endpoint(shoulder_deg, elbow_deg):
    """The hand from the arm's angles (Table 2's degrees)."""
    s, e = np.radians(shoulder_deg), np.radians(elbow_deg)
    return np.array([L_U * np.cos(s) + L_F * np.cos(s + e), L_U * np.sin(s) + L_F * np.sin(s + e)])


BASE = arm_endpoint(62.708, 77.260) + np.array([0.0, 0.65])  # 0.65 m behind location 1's hand


def spec_fk(q):
    """``x = p_b + [L_s cos q1 + L_e cos q2, L_s sin q1 + L_e sin q2]``."""
    return jnp.asarray(BASE) + jnp.stack(
        [L_S * jnp.cos(q[0]) + L_E * jnp.cos(q[1]), L_S * jnp.sin(q[0]) + L_E * jnp.sin(q[1])]
    )


def spec_kinetic_energy(q, qd):
    """The parallelogram's kinetic energy, ``T = (c1 qd1^2 + 2 c2 cos(q1 - q2) qd1 qd2 + c3 qd2^2) / 2``."""
    return 0.5 * (C1 * qd[0] ** 2 + 2 * C2 * jnp.cos(q[0] - q[1]) * qd[0] * qd[1] + C3 * qd[1] ** 2)


@pytest.mark.parametrize("location", [1, 2, 3, 4])
def test_fk_inverts_ik_on_the_spec_branch(location):
    x = jnp.asarray(location_endpoint(location))
    q = robot.ik(x)
    np.testing.assert_allclose(robot.fk(q), x, rtol=0, atol=1e-15)
    assert 0.0 < float(q[0] - q[1]) < np.pi
    assert robot.workspace_margin(q) >= 0.16


def test_location_1_matches_the_spec():
    q = robot.ik(jnp.asarray(location_endpoint(1)))
    np.testing.assert_allclose(np.degrees(q), [-37.70, -128.69], atol=0.01)
    np.testing.assert_allclose(robot.cartesian_inertia(q), [[1.447, 0.735], [0.735, 1.783]], atol=1e-3)
    np.testing.assert_allclose(ROBOT_BASE, [-0.148729, 1.042452], atol=1e-6)
    np.testing.assert_allclose(ROBOT_BASE, BASE, rtol=0, atol=1e-15)


def test_ik_rejects_unreachable_points():
    with pytest.raises(ValueError, match="outside the robot's workspace"):
        robot.ik(jnp.asarray(ROBOT_BASE + np.array([0.0, -2.0])))


@pytest.mark.parametrize("q", [[-0.6, -2.2], [0.3, -1.0], [-1.2, -2.9]])
def test_jacobian_is_derivative_of_fk(q):
    q = jnp.asarray(q)
    np.testing.assert_allclose(robot.fk(q), spec_fk(q), rtol=0, atol=1e-15)
    np.testing.assert_allclose(robot.jacobian(q), jax.jacfwd(spec_fk)(q), rtol=1e-14, atol=1e-15)


@pytest.mark.parametrize("q", [[-0.6, -2.2], [0.3, -1.0], [2.0, 2.0]])
def test_mass_matrix_is_symmetric_positive_definite_and_the_hessian_of_kinetic_energy(q):
    q = jnp.asarray(q)
    m = robot.mass_matrix(q)
    np.testing.assert_array_equal(m, m.T)
    assert np.all(np.linalg.eigvalsh(m) > 0)
    np.testing.assert_allclose(jax.hessian(spec_kinetic_energy, argnums=1)(q, jnp.zeros(2)), m, rtol=1e-14)
    qd = jnp.array([0.7, -1.3])
    np.testing.assert_allclose(robot.kinetic_energy(q, qd), spec_kinetic_energy(q, qd), rtol=1e-14)


def _lagrangian_qdd(q, qd, z, fu, params):
    """qdd from Euler-Lagrange of the spec's kinetic energy plus the arm, all written in this file
    (the friction torque apart: LuGre is checked in test_friction.py)."""
    dT_dqd = jax.grad(spec_kinetic_energy, argnums=1)
    m = jax.jacfwd(dT_dqd, argnums=1)(q, qd)
    h = jax.jacfwd(dT_dqd, argnums=0)(q, qd) @ qd - jax.grad(spec_kinetic_energy, argnums=0)(q, qd)
    np.testing.assert_allclose(robot.velocity_torque(q, qd), h, rtol=1e-12, atol=1e-15)
    j = jax.jacfwd(spec_fk)(q)
    jd_qd = jax.jvp(lambda q_: jax.jacfwd(spec_fk)(q_), (q,), (qd,))[1] @ qd
    arm, fr = params.arm, params.friction
    tau_f = jnp.stack([fr.joint(i).torque_and_rate(qd[i], z[i])[0] for i in range(2)])
    x = spec_fk(q)
    # M qdd + h + tau_f = J^T (F_u - F_h),  F_h = M_h (J qdd + Jd qd) + B_h J qd + K_h (x - x0)
    lhs = m + j.T @ arm.mass @ j
    rhs = j.T @ (fu - arm.mass @ jd_qd - arm.damping @ (j @ qd) - arm.stiffness @ (x - params.x0)) - h - tau_f
    return jnp.linalg.solve(lhs, rhs)


@pytest.mark.parametrize("friction_level", [0, 2])
@pytest.mark.parametrize("location", [1, 3])
def test_coupled_acceleration_matches_lagrangian(friction_level, location):
    p = paper.trial("pd", friction_level, location)
    q = p.q0 + jnp.array([0.01, -0.02])
    qd = jnp.array([0.3, -0.5])
    z = jnp.array([2e-6, -5e-6])
    fu = jnp.array([1.5, -2.0])
    s = PlantState(q[0], q[1], qd[0], qd[1], z[0], z[1], 0.0, 0.0)
    d = plant_derivative(s, fu, plant_model(p.q0, p.x0, p.arm, p.friction, p.robot))
    expected = _lagrangian_qdd(q, qd, z, fu, p)
    np.testing.assert_allclose([d.qd1, d.qd2], expected, rtol=1e-11, atol=1e-12)
    np.testing.assert_allclose([d.xi1, d.xi2], robot.fk(q) - p.x0, rtol=1e-12, atol=1e-16)
