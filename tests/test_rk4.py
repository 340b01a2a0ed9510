"""The RK4 solver (``armimp_jax._solver.rk4``): its fast and grad kernels against the
reference one, and its options."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import armimp_jax as aj
from armimp_jax import paper
from armimp_jax._model.plant import plant_model, rest_state

# Bound: the kernels differ only by round-off (rotated vs evaluated cos/sin, ~1 ulp per
# substep, re-seeded every period); trajectories are not chaotic (docs/model.md section 6), so
# over a record of seconds the relative difference stays many orders below the physics.
BOUND = 1e-9


def _kernel_runs(controller, n_samples, locations, substeps=100):
    """The same three trials (friction 0, 1, 2) run with each kernel, keyed by kernel name."""
    fd = aj.perturbation(jax.random.PRNGKey(4), n_samples, paper.perturbation_peak(1))
    params = aj.batch.stack_trials([paper.trial(controller, f, loc) for f, loc in zip((0, 1, 2), locations)])
    runs = {}
    for kernel in aj.solvers.RK4.KERNELS:
        numerics = aj.Numerics(solver=aj.solvers.RK4(kernel=kernel), substeps=substeps)
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


def test_bad_options_are_refused_with_the_allowed_choices():
    with pytest.raises(ValueError, match="RK4: unknown kernel 'gpu'; allowed: 'fast', 'reference', 'grad'"):
        aj.solvers.RK4(kernel="gpu")
    p = paper.trial("pd", 0, 1)
    model = plant_model(p.q0, p.x0, p.arm, p.friction, p.robot)
    with pytest.raises(ValueError, match="unknown checkpoint 'step'; allowed: 'period', 'substep'"):
        aj.solvers.RK4().integrate_period(
            rest_state(p.q0), jnp.zeros(2), model, period=1e-3, substeps=2, checkpoint="step"
        )
