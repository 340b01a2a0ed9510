"""The unconstrained <-> symmetric positive definite map (armimp_jax._design.spd)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from armimp_jax._design.spd import n_theta, spd_from_theta, theta_from_spd


@pytest.mark.parametrize("structure,n", [("diagonal", 2), ("full", 2), ("full", 3), ("diagonal", 4)])
def test_round_trip_and_positive_definite(structure, n):
    rng = np.random.default_rng(3)
    for _ in range(5):
        theta = jnp.asarray(rng.normal(size=n_theta(n, structure)))
        m = np.asarray(spd_from_theta(theta, structure))
        np.testing.assert_allclose(m, m.T, rtol=0, atol=0)
        assert np.all(np.linalg.eigvalsh(m) > 0)
        np.testing.assert_allclose(theta_from_spd(m, structure), theta, rtol=0, atol=1e-12)


def test_full_matches_a_cholesky_factor():
    a = np.array([[2.0, 0.3, -0.1], [0.3, 1.5, 0.2], [-0.1, 0.2, 0.8]])
    theta = theta_from_spd(a, "full")
    lower = np.linalg.cholesky(a)
    np.testing.assert_allclose(np.asarray(theta)[[0, 2, 5]], np.log(np.diag(lower)), rtol=1e-14)
    np.testing.assert_allclose(spd_from_theta(theta, "full"), a, rtol=1e-13)


def test_gradient_against_central_differences():
    theta = jnp.array([0.1, -0.4, 0.3])

    def f(t):
        return jnp.sum(spd_from_theta(t, "full") * jnp.array([[1.0, 2.0], [-0.5, 3.0]]))

    g = jax.grad(f)(theta)
    h = 1e-6
    fd = [(f(theta.at[i].add(h)) - f(theta.at[i].add(-h))) / (2 * h) for i in range(3)]
    np.testing.assert_allclose(g, fd, rtol=1e-8)


def test_bad_input_is_one_line():
    with pytest.raises(
        ValueError, match=r"^M must be symmetric positive definite, got \[\[1.0, 2.0\], \[2.0, 1.0\]\]$"
    ):
        theta_from_spd([[1.0, 2.0], [2.0, 1.0]], "full", name="M")
    with pytest.raises(ValueError, match="n \\(n \\+ 1\\) / 2 entries, got 4"):
        spd_from_theta(jnp.zeros(4), "full")
    with pytest.raises(ValueError, match="structure"):
        n_theta(2, "lower")
