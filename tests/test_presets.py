"""The presets against the paper's tables, written out here (docs/model.md sections 3, 4, 7, 8,
10: Tables 1-3 and the paper's gains), not against an earlier output of the library."""

import math

import jax
import numpy as np
import pytest

import armimp_jax as aj
from armimp_jax import presets

# Table 1: (tau_c, tau_s) [N m]; levels 1 and 2 with sigma0 = 1e5 N m/rad, sigma1 = sqrt(1e5)
# N m s/rad, sigma2 = 0.5 N m s/rad, v_s = 0.001 rad/s; level 0 no friction at all.
TABLE_1 = {1: (1.0, 1.5), 2: (4.0, 6.0)}
# Table 2: th_s, th_e [deg], M_h [kg], B_h [N s/m], K_h [N/m], and the endpoint the spec gives [m]
TABLE_2 = {
    1: (
        62.708,
        77.260,
        [[1.54, -0.57], [-0.65, 0.94]],
        [[7.17, -6.14], [-6.19, 12.08]],
        [[105.72, -104.11], [-127.35, 234.78]],
        (-0.1487, 0.3925),
    ),
    2: (
        41.870,
        62.578,
        [[0.79, -0.49], [-0.59, 1.56]],
        [[3.24, 0.81], [1.18, 22.98]],
        [[31.53, 41.36], [13.83, 380.55]],
        (0.0765, 0.4500),
    ),
    3: (
        102.185,
        59.420,
        [[1.58, 0.00], [-0.10, 0.49]],
        [[20.86, -10.69], [-12.32, 10.27]],
        [[232.77, -145.13], [-147.64, 173.38]],
        (-0.3480, 0.3063),
    ),
    4: (
        37.301,
        126.831,
        [[2.24, -0.51], [-0.54, 0.71]],
        [[13.17, -5.33], [-5.39, 6.93]],
        [[146.30, -63.43], [-61.26, 98.45]],
        (-0.1408, 0.2148),
    ),
}
TABLE_3 = {1: 2.25, 2: 3.75, 3: 4.50}  # peak |F_Delta| per axis [N]
L_U, L_F = 0.21, 0.32  # upper arm, forearm plus hand [m]


@pytest.mark.parametrize("location", [1, 2, 3, 4])
def test_arms_are_table_2(location):
    th_s, th_e, mass, damping, stiffness, endpoint = TABLE_2[location]
    arm = presets.arm(location)
    np.testing.assert_array_equal(arm.mass, mass)
    np.testing.assert_array_equal(arm.damping, damping)
    np.testing.assert_array_equal(arm.stiffness, stiffness)
    s, e = math.radians(th_s), math.radians(th_e)
    hand = [L_U * math.cos(s) + L_F * math.cos(s + e), L_U * math.sin(s) + L_F * math.sin(s + e)]
    np.testing.assert_allclose(arm.endpoint, hand, rtol=0, atol=1e-15)
    np.testing.assert_allclose(arm.endpoint, endpoint, rtol=0, atol=5e-5)  # the spec's four decimals


@pytest.mark.parametrize("level", [0, 1, 2])
def test_friction_levels_are_table_1(level):
    p = presets.friction(level)
    if level == 0:  # no Coulomb, stiction or viscous torque, and no bristles
        for name in ("tau_c", "tau_s", "sigma0", "sigma1", "sigma2"):
            np.testing.assert_array_equal(getattr(p, name), 0.0)
        return
    tau_c, tau_s = TABLE_1[level]
    for name, want in dict(tau_c=tau_c, tau_s=tau_s, sigma0=1e5, sigma1=316.227766, sigma2=0.5, v_s=1e-3).items():
        np.testing.assert_allclose(getattr(p, name), [want, want], rtol=1e-9, err_msg=name)  # both joints


@pytest.mark.parametrize("level", [1, 2, 3])
def test_perturbation_peaks_are_table_3(level):
    np.testing.assert_array_equal(presets.perturbation_peak(level), [TABLE_3[level]] * 2)


def test_the_papers_trials_carry_its_gains_and_start_at_rest_at_the_hand():
    """PD: K_p = 250 I N/m, K_v = 4 I N s/m; IMBIC: Mhat = 0.25 I kg, desired dynamics M_x(q0),
    K_v, K_p; the robot starts at q0 = ik(hand) (location 1: -37.70 and -128.69 deg)."""
    pd = presets.trial("pd", 1, 1)
    np.testing.assert_array_equal(pd.controller.kp, 250.0 * np.eye(2))
    np.testing.assert_array_equal(pd.controller.kv, 4.0 * np.eye(2))
    np.testing.assert_allclose(np.degrees(pd.q0), [-37.70, -128.69], atol=0.01)
    np.testing.assert_allclose(pd.x0, TABLE_2[1][5], atol=5e-5)
    imbic = presets.trial("imbic", 2, 3).controller
    np.testing.assert_array_equal(imbic.mhat, 0.25 * np.eye(2))
    np.testing.assert_array_equal(imbic.k_rd, 250.0 * np.eye(2))
    np.testing.assert_array_equal(imbic.b_rd, 4.0 * np.eye(2))
    from armimp_jax._model.robot import cartesian_inertia

    np.testing.assert_allclose(imbic.m_rd, cartesian_inertia(presets.trial("imbic", 2, 3).q0), rtol=1e-12)


def test_friction_level_0_leaves_the_bristles_at_zero():
    """docs/model.md section 4: at level 0 the bristle state is unused and stays exactly 0."""
    trial = presets.trial("pd", 0, 1)
    f = aj.perturbation(jax.random.key(3), 300, TABLE_3[1])
    sim = jax.jit(aj.simulate, static_argnames="numerics")(
        trial, f, numerics=aj.Numerics(solver=aj.solvers.RK4(), substeps=5)
    )
    np.testing.assert_array_equal(sim.z, 0.0)
    assert np.abs(np.asarray(sim.x) - np.asarray(trial.x0)).max() > 1e-5  # it moved
