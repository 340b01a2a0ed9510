"""LuGre: steady sliding friction, pre-sliding stiffness, and the exact zero of level 0.
CoulombViscous: its torque and slope in closed form, the plant's joint accelerations it gives,
and its one-line refusals."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import armimp_jax as aj
from armimp_jax import paper
from armimp_jax._model.friction import steady_state_friction, stribeck
from armimp_jax._model.plant import PlantState, plant_derivative, plant_model
from armimp_jax._model.robot import jacobian

# The paper's Table 1 (docs/model.md section 4), written out here: (tau_c, tau_s) [N m] per
# level; sigma0 = 1e5 N m/rad, sigma1 = sqrt(1e5) N m s/rad, sigma2 = 0.5 N m s/rad, v_s = 1e-3 rad/s.
TABLE_1 = {1: (1.0, 1.5), 2: (4.0, 6.0)}
SIGMA0, SIGMA1, SIGMA2, V_S = 1e5, math.sqrt(1e5), 0.5, 1e-3


def g_of(v, level):
    """The Stribeck curve from its formula: ``g(v) = tau_c + (tau_s - tau_c) exp(-(v / v_s)^2)``."""
    tau_c, tau_s = TABLE_1[level]
    return tau_c + (tau_s - tau_c) * math.exp(-((v / V_S) ** 2))


@pytest.mark.parametrize("level", [1, 2])
@pytest.mark.parametrize("v", [-0.2, -2e-3, 5e-4, 0.05])
def test_constant_velocity_reaches_the_steady_friction(level, v):
    p = paper.friction(level).joint(0)
    g = g_of(v, level)
    np.testing.assert_allclose(float(stribeck(jnp.asarray(v), p)), g, rtol=1e-14)
    v = jnp.asarray(v)

    # The bristle ODE relaxes with time constant g(v) / (sigma0 |v|): integrate 40 of them.
    tau_z = g / (SIGMA0 * abs(float(v)))
    h = tau_z / 200

    def step(z, _):  # RK4 on the bristle ODE at fixed velocity

        def f(zz):
            return p.torque_and_rate(v, zz)[1]

        k1 = f(z)
        k2 = f(z + 0.5 * h * k1)
        k3 = f(z + 0.5 * h * k2)
        k4 = f(z + h * k3)
        return z + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4), None

    z, _ = jax.lax.scan(step, jnp.asarray(0.0), None, length=8000)
    tau, zd = p.torque_and_rate(v, z)
    # at steady sliding zd = 0, so z = g(v) sign(v) / sigma0 and tau = g(v) sign(v) + sigma2 v
    np.testing.assert_allclose(tau, g * np.sign(float(v)) + SIGMA2 * float(v), rtol=1e-9)
    np.testing.assert_allclose(steady_state_friction(v, p), g * np.sign(float(v)) + SIGMA2 * float(v), rtol=1e-14)
    assert abs(float(zd)) < 1e-9 * abs(float(v))


@pytest.mark.parametrize("level", [1, 2])
def test_small_motions_see_the_bristle_stiffness(level):
    """A 0.01 microradian oscillation stays in linear pre-sliding (|z| << g / sigma0 = 1.5e-5 rad):
    tau ~ sigma0 q + (sigma1 + sigma2) qd; the bristle nonlinearity is ~sigma0 |z| / g = 0.07%."""
    p = paper.friction(level).joint(0)
    amp, w, h = 1e-8, 2 * np.pi * 2.0, 1e-5
    t = np.arange(0, 0.5, h)
    q, qd = amp * np.sin(w * t), amp * w * np.cos(w * t)

    def step(z, v):
        zd = p.torque_and_rate(v, z)[1]
        return z + h * zd, p.torque_and_rate(v, z)[0]

    _, tau = jax.lax.scan(step, jnp.asarray(0.0), jnp.asarray(qd))
    expected = SIGMA0 * q + (SIGMA1 + SIGMA2) * qd
    np.testing.assert_allclose(tau[1000:], expected[1000:], atol=3e-3 * np.abs(expected).max())


def test_level_0_is_exactly_zero_with_finite_gradients():
    p = paper.friction(0).joint(0)
    for v, z in [(0.0, 0.0), (0.3, 1e-3), (-1e-9, 0.0)]:
        tau, zd = p.torque_and_rate(jnp.asarray(v), jnp.asarray(z))
        assert float(tau) == 0.0 and float(zd) == 0.0  # no bristles: z stays 0
        grads = jax.grad(
            lambda v_, z_, p_: p_.torque_and_rate(v_, z_)[0] + p_.torque_and_rate(v_, z_)[1], argnums=(0, 1, 2)
        )(jnp.asarray(v), jnp.asarray(z), p)
        assert all(np.all(np.isfinite(g)) for g in jax.tree.leaves(grads))


def test_without_bristles_friction_is_viscous_only():
    """tau_c = tau_s = 0 with the bristle parameters left in place: tau_f = sigma2 v (docs/model.md section 4),
    not a 1e5 N m/rad spring, whatever the (unused) bristle state."""
    p = aj.LuGre(0.0, 0.0).joint(0)
    for v, z in [(0.2, 0.0), (-0.05, 3e-4), (0.0, 1e-3)]:
        tau, zd = p.torque_and_rate(jnp.asarray(v), jnp.asarray(z))
        assert float(zd) == 0.0
        np.testing.assert_allclose(float(tau), 0.5 * v, rtol=1e-15)


def test_unknown_level_is_rejected():
    with pytest.raises(ValueError, match="unknown friction level 3; allowed: 0, 1, 2"):
        paper.friction(3)


# KINARM's model (the law's docstring): tau_c 0.06 N m, viscous 0.0025 N m s/rad, v_s 0.01 rad/s;
# the second joint's values differ, so a law that mixed the joints up would show.
KINARM = dict(tau_c=[0.06, 0.09], viscous=[0.0025, 0.004], v_s=[0.01, 0.02])


def _coulomb_viscous_torque(v, joint):
    """``tau_c tanh(v / v_s) + viscous v`` [N m] from its formula (module docstring), and its slope."""
    tau_c, viscous, v_s = (KINARM[n][joint] for n in ("tau_c", "viscous", "v_s"))
    t = np.tanh(v / v_s)
    return tau_c * t + viscous * v, tau_c / v_s * (1.0 - t * t)


def test_coulomb_viscous_is_the_smoothed_coulomb_torque_plus_viscous_friction():
    law = aj.CoulombViscous(**KINARM)
    v = np.array([-0.5, -0.013, -1e-4, 0.0, 2e-3, 0.01, 0.3, 4.0])  # [rad/s], within and beyond v_s
    for i in range(2):
        joint = law.joint(i)
        tau, zd = joint.torque_and_rate(jnp.asarray(v), jnp.zeros_like(v))
        expected, slope = _coulomb_viscous_torque(v, i)
        np.testing.assert_allclose(tau, expected, rtol=1e-14, atol=1e-18)
        assert np.all(np.asarray(zd) == 0.0)  # no internal state
        # 1 - tanh^2 loses its digits far out on the tanh: round-off relative to the slope at rest
        atol = 1e-14 * slope.max()
        np.testing.assert_allclose(joint.static_slope(jnp.asarray(v)), slope, rtol=1e-13, atol=atol)
        # the slope the implicit integrators take is the torque's own derivative
        grad = jax.vmap(jax.grad(joint.static_torque))(jnp.asarray(v))
        np.testing.assert_allclose(grad, slope, rtol=1e-13, atol=atol)
        assert float(joint.viscous_coefficient()) == KINARM["viscous"][i]
    assert float(law.joint(0).static_slope(0.0)) == pytest.approx(0.06 / 0.01, rel=1e-15)  # stiff at rest
    assert law.has_coulomb() and not law.without_coulomb().has_coulomb()
    np.testing.assert_array_equal(law.without_coulomb().viscous, KINARM["viscous"])
    np.testing.assert_array_equal(aj.CoulombViscous(0.06).viscous, [0.0, 0.0])  # a scalar serves both joints


def test_the_plant_feels_coulomb_viscous_as_a_torque_resisting_each_joints_motion():
    """``M qdd + h + tau_f = J^T F``: at any state the law's joint accelerations are those of the
    frictionless plant under the extra hand force ``-J^-T tau_f(qd)``, with ``tau_f`` the formula."""
    endpoint = paper.arm(2).endpoint
    law, free = aj.CoulombViscous(**KINARM), aj.CoulombViscous(0.0)
    trials = [aj.make_trial(aj.PD(), arm=aj.presets.no_arm(endpoint), friction=f) for f in (law, free)]
    models = [plant_model(t.q0, t.x0, t.arm, t.friction, t.robot) for t in trials]
    q0 = np.asarray(trials[0].q0)
    fu = np.array([1.5, -0.7])  # [N]
    for qd in ([0.004, -0.03], [-0.8, 0.25], [0.0, 1e-3]):
        state = PlantState(*(jnp.asarray(v) for v in (*q0, *qd, 0.0, 0.0, 0.0, 0.0)))
        tau_f = np.array([_coulomb_viscous_torque(qd[i], i)[0] for i in range(2)])
        extra = -np.linalg.solve(np.asarray(jacobian(jnp.asarray(q0), trials[0].robot)).T, tau_f)
        with_law = plant_derivative(state, jnp.asarray(fu), models[0])
        without = plant_derivative(state, jnp.asarray(fu + extra), models[1])
        np.testing.assert_allclose([with_law.qd1, with_law.qd2], [without.qd1, without.qd2], rtol=1e-12, atol=1e-12)
        np.testing.assert_array_equal([with_law.z1, with_law.z2], [0.0, 0.0])


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(tau_c=-0.06), r"CoulombViscous: tau_c must be >= 0 N m, got \[-0.06, -0.06\]"),
        (dict(tau_c=0.06, viscous=[0.0025, -1e-3]), r"CoulombViscous: viscous must be >= 0 N m s/rad, got"),
        (dict(tau_c=0.06, v_s=0.0), r"CoulombViscous: v_s must be > 0 rad/s, got \[0.0, 0.0\]"),
        (dict(tau_c=0.06, v_s=-0.01), r"CoulombViscous: v_s must be > 0 rad/s"),
        (dict(tau_c=[0.06, 0.06, 0.06]), r"CoulombViscous: tau_c \[N m\] must be a scalar or shape \(2,\), got"),
        (dict(tau_c=np.zeros((2, 2))), r"tau_c \[N m\] must be a scalar or shape \(2,\), got shape \(2, 2\)"),
        (dict(tau_c=0.06, viscous=math.nan), r"CoulombViscous: viscous \[N m s/rad\] must be finite, got"),
        (dict(tau_c="0.06 N m"), r"CoulombViscous: tau_c \[N m\] must be numeric, got '0.06 N m'"),
    ],
)
def test_coulomb_viscous_refuses_bad_values_in_one_line(kwargs, message):
    with pytest.raises(ValueError, match=message) as err:
        aj.CoulombViscous(**kwargs)
    assert "\n" not in str(err.value)
