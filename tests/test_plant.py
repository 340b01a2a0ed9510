"""The plant's equations (``armimp_jax._model.plant``): the hand's displacement and the force
sensor, against the robot's kinematics differentiated by JAX."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from armimp_jax import paper
from armimp_jax._model import robot
from armimp_jax._model.plant import PlantState, displacement, measure, plant_derivative, plant_model, trig_of_angles


def _state(p, dq, qd, z):
    return PlantState(p.q0[0] + dq[0], p.q0[1] + dq[1], qd[0], qd[1], z[0], z[1], 0.0, 0.0)


@pytest.mark.parametrize("location", [1, 2, 3, 4])
def test_displacement_is_exactly_zero_at_the_equilibrium_and_fk_elsewhere(location):
    """Rest stays bitwise rest (trig differences against q0's), and away from q0 the
    displacement is ``fk(q) - x0``."""
    p = paper.trial("pd", 1, location)
    model = plant_model(p.q0, p.x0, p.arm, p.friction, p.robot)
    assert all(float(e) == 0.0 for e in displacement(trig_of_angles(p.q0), model))
    q = p.q0 + jnp.array([0.03, -0.05])
    np.testing.assert_allclose(displacement(trig_of_angles(q), model), robot.fk(q, p.robot) - p.x0, rtol=1e-13)


@pytest.mark.parametrize("friction_level, location", [(0, 1), (1, 2), (2, 3)])
def test_measured_hand_force_is_the_arm_impedance_force_of_the_plant_motion(friction_level, location):
    """``F_h = M_h xdd + B_h xd + K_h (x - x0)``, with ``xd = J qd`` and ``xdd`` the time
    derivative of ``J(q) qd`` along the plant's own ``qdd`` (forward-mode JAX of ``fk``, not
    the plant's hand-written ``Jd qd``), while the command acts and the bristles are loaded."""
    p = paper.trial("imbic", friction_level, location)
    model = plant_model(p.q0, p.x0, p.arm, p.friction, p.robot)
    s = _state(p, (0.01, -0.02), (0.3, -0.5), (2e-6, -5e-6))
    fu = jnp.array([1.5, -2.0])
    x, xd, fh = measure(s, fu, model)
    d = plant_derivative(s, fu, model)
    q, qd, qdd = jnp.array([s.q1, s.q2]), jnp.array([s.qd1, s.qd2]), jnp.array([d.qd1, d.qd2])

    def hand_velocity(q, qd):
        return jax.jvp(lambda q: robot.fk(q, p.robot), (q,), (qd,))[1]

    xd_ad, xdd = jax.jvp(hand_velocity, (q, qd), (qd, qdd))
    expected = p.arm.mass @ xdd + p.arm.damping @ xd_ad + p.arm.stiffness @ (robot.fk(q, p.robot) - p.x0)
    np.testing.assert_allclose(x, robot.fk(q, p.robot), rtol=1e-14)
    np.testing.assert_allclose(xd, xd_ad, rtol=1e-13)
    np.testing.assert_allclose(fh, expected, rtol=1e-11, atol=1e-12 * float(jnp.abs(expected).max()))
