"""LuGre: steady sliding friction, pre-sliding stiffness, and the exact zero of level 0."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import armimp_jax as aj
from armimp_jax import paper
from armimp_jax._model.friction import steady_state_friction, stribeck

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
            return aj.lugre(v, zz, p)[1]

        k1 = f(z)
        k2 = f(z + 0.5 * h * k1)
        k3 = f(z + 0.5 * h * k2)
        k4 = f(z + h * k3)
        return z + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4), None

    z, _ = jax.lax.scan(step, jnp.asarray(0.0), None, length=8000)
    tau, zd = aj.lugre(v, z, p)
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
        zd = aj.lugre(v, z, p)[1]
        return z + h * zd, aj.lugre(v, z, p)[0]

    _, tau = jax.lax.scan(step, jnp.asarray(0.0), jnp.asarray(qd))
    expected = SIGMA0 * q + (SIGMA1 + SIGMA2) * qd
    np.testing.assert_allclose(tau[1000:], expected[1000:], atol=3e-3 * np.abs(expected).max())


def test_level_0_is_exactly_zero_with_finite_gradients():
    p = paper.friction(0).joint(0)
    for v, z in [(0.0, 0.0), (0.3, 1e-3), (-1e-9, 0.0)]:
        tau, zd = aj.lugre(jnp.asarray(v), jnp.asarray(z), p)
        assert float(tau) == 0.0 and float(zd) == 0.0  # no bristles: z stays 0
        grads = jax.grad(lambda v_, z_, p_: aj.lugre(v_, z_, p_)[0] + aj.lugre(v_, z_, p_)[1], argnums=(0, 1, 2))(
            jnp.asarray(v), jnp.asarray(z), p
        )
        assert all(np.all(np.isfinite(g)) for g in jax.tree.leaves(grads))


def test_without_bristles_friction_is_viscous_only():
    """tau_c = tau_s = 0 with the bristle parameters left in place: tau_f = sigma2 v (docs/model.md section 4),
    not a 1e5 N m/rad spring, whatever the (unused) bristle state."""
    p = aj.LuGre(0.0, 0.0).joint(0)
    for v, z in [(0.2, 0.0), (-0.05, 3e-4), (0.0, 1e-3)]:
        tau, zd = aj.lugre(jnp.asarray(v), jnp.asarray(z), p)
        assert float(zd) == 0.0
        np.testing.assert_allclose(float(tau), 0.5 * v, rtol=1e-15)


def test_unknown_level_is_rejected():
    with pytest.raises(ValueError, match="unknown friction level 3; allowed: 0, 1, 2"):
        paper.friction(3)
