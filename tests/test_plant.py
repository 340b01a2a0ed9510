"""The plant's integration kernels: the small-angle rotation, and the fast and grad RK4
kernels against the reference one."""

import pathlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import armimp_jax as aj
from armimp_jax import paper
from armimp_jax._model.plant import KERNELS, Trig, rotate

ROOT = pathlib.Path(__file__).resolve().parents[1]


def test_rotation_is_exact_to_round_off():
    q = jnp.array([-0.6, -2.2, 1.3])
    t = Trig(jnp.cos(q), jnp.sin(q), jnp.cos(-q), jnp.sin(-q))
    for d in (0.0, 1e-9, 1e-6, 1e-4, 0.02):
        r = rotate(t, jnp.full(3, d), jnp.full(3, -d))
        np.testing.assert_allclose(r.c1, np.cos(q + d), rtol=0, atol=3e-16)
        np.testing.assert_allclose(r.s1, np.sin(q + d), rtol=0, atol=3e-16)
        np.testing.assert_allclose(r.c2, np.cos(-q - d), rtol=0, atol=3e-16)
        np.testing.assert_allclose(r.s2, np.sin(-q - d), rtol=0, atol=3e-16)
    same = rotate(t, jnp.zeros(3), jnp.zeros(3))  # rest stays bitwise at rest
    assert all(np.array_equal(a, b) for a, b in zip(same, t))


# Bound: the kernels differ only by round-off (rotated vs evaluated cos/sin, ~1 ulp per
# substep, re-seeded every period); trajectories are not chaotic (spec section 14), so
# over a record of seconds the relative difference stays many orders below the physics.
BOUND = 1e-9


def _kernel_runs(controller, n_samples, locations, substeps=100):
    """The same three trials (friction 0, 1, 2) run with each kernel, keyed by kernel name."""
    fd = aj.perturbation(jax.random.PRNGKey(4), n_samples, paper.perturbation_peak(1))
    params = aj.stack_trials([paper.trial(controller, f, loc) for f, loc in zip((0, 1, 2), locations)])
    runs = {}
    for kernel in KERNELS:
        numerics = aj.Numerics(substeps=substeps, kernel=kernel)
        batched = jax.jit(jax.vmap(lambda t, f, numerics=numerics: aj.simulate(t, f, numerics=numerics)))
        runs[kernel] = batched(params, jnp.stack([fd] * 3))
    return runs


@pytest.mark.parametrize("controller", ["pd", "imbic"])
def test_fast_and_grad_kernels_agree_with_reference(controller):
    runs = _kernel_runs(controller, 1500, (1, 2, 3), substeps=50)
    for kernel in ("fast", "grad"):
        for name in ("x", "xd", "fh", "fu", "q"):
            a, b = np.asarray(getattr(runs[kernel], name)), np.asarray(getattr(runs["reference"], name))
            if name == "x":
                a, b = a - a[:, :1], b - b[:, :1]  # compare displacements, not the 0.4 m offset
            scale = np.abs(b).max(axis=(1, 2), keepdims=True)
            assert np.all(np.abs(a - b) <= BOUND * scale), (kernel, name, (np.abs(a - b) / scale).max())


@pytest.mark.slow
@pytest.mark.parametrize("controller", ["pd", "imbic"])
def test_fast_and_grad_kernels_agree_with_reference_over_50_s(controller):
    runs = _kernel_runs(controller, 50_000, (1, 1, 1))
    xs = {kernel: np.asarray(r.x) for kernel, r in runs.items()}
    scale = np.abs(xs["reference"] - xs["reference"][:, :1]).max(axis=(1, 2), keepdims=True)
    for kernel in ("fast", "grad"):
        assert np.all(np.abs(xs[kernel] - xs["reference"]) <= BOUND * scale), kernel
