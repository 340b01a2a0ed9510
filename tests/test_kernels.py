"""The fast, grad and batch RK4 kernels against the reference one, and sharded against unsharded runs."""

import json
import os
import pathlib
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import armimp_jax as aj
from armimp_jax.plant import KERNELS, Trig, rotate

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


def _kernel_runs(controller, n_samples, locations, **options):
    """The same three trials (friction 0, 1, 2) run with each kernel, keyed by kernel name."""
    fd = aj.perturbation(jax.random.PRNGKey(4), n_samples, aj.perturbation_peak(1))
    batched = jax.jit(jax.vmap(aj.simulate))
    runs = {}
    for kernel in KERNELS:
        params = aj.stack_trials(
            [aj.trial_params(controller, f, loc, kernel=kernel, **options) for f, loc in zip((0, 1, 2), locations)]
        )
        runs[kernel] = batched(params, jnp.stack([fd] * 3))
    return runs


@pytest.mark.parametrize("controller", ["pd", "imbic"])
def test_fast_grad_and_batch_kernels_agree_with_reference(controller):
    runs = _kernel_runs(controller, 1500, (1, 2, 3), substeps=50)
    for kernel in ("fast", "grad", "batch"):
        for name in ("x", "xd", "fh", "fu", "q"):
            a, b = np.asarray(getattr(runs[kernel], name)), np.asarray(getattr(runs["reference"], name))
            if name == "x":
                a, b = a - a[:, :1], b - b[:, :1]  # compare displacements, not the 0.4 m offset
            scale = np.abs(b).max(axis=(1, 2), keepdims=True)
            assert np.all(np.abs(a - b) <= BOUND * scale), (kernel, name, (np.abs(a - b) / scale).max())


@pytest.mark.slow
@pytest.mark.parametrize("controller", ["pd", "imbic"])
def test_fast_grad_and_batch_kernels_agree_with_reference_over_50_s(controller):
    runs = _kernel_runs(controller, 50_000, (1, 1, 1))
    xs = {kernel: np.asarray(r.x) for kernel, r in runs.items()}
    scale = np.abs(xs["reference"] - xs["reference"][:, :1]).max(axis=(1, 2), keepdims=True)
    for kernel in ("fast", "grad", "batch"):
        assert np.all(np.abs(xs[kernel] - xs["reference"]) <= BOUND * scale), kernel


SHARDED = """
import json, sys
from armimp_jax.runtime import configure
n = configure(host_devices=2, hoist_small_loops=False, vector_width=json.loads(sys.argv[2]))
import jax, numpy as np, armimp_jax as aj
from armimp_jax import sweep
params = aj.stack_trials([aj.trial_params(c, f, 1 + f, substeps=5) for c in ["imbic"] for f in (0, 1, 2)])
fd = np.stack([np.asarray(aj.perturbation(jax.random.PRNGKey(i), 600, 2.25)) for i in range(3)])
mesh = sweep.make_mesh(jax.devices()[:int(sys.argv[1])])
r = sweep.simulate_batch(params, fd, mesh=mesh, chunk_samples=250)
compiles = sweep._chunk._cache_size()  # three chunks, one compiled loop
out = dict(devices=mesh.size, seen=n, compiles=compiles, x=r.x.tolist(), fh=r.fh.tolist(), fu=r.fu.tolist())
print(json.dumps(out))
"""


def _run_sharded(n_devices, vector_width=None):
    env = dict(os.environ, XLA_FLAGS="")
    proc = subprocess.run(
        [sys.executable, "-c", SHARDED, str(n_devices), json.dumps(vector_width)],
        capture_output=True,
        text=True,
        env=env,
        cwd=ROOT,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _plain_batch():
    """The subprocess's batch, vmapped in this process (XLA's default vector width)."""
    params = aj.stack_trials([aj.trial_params("imbic", f, 1 + f, substeps=5) for f in (0, 1, 2)])
    fd = jnp.stack([aj.perturbation(jax.random.PRNGKey(i), 600, 2.25) for i in range(3)])
    return jax.jit(jax.vmap(aj.simulate))(params, fd)


def test_sharded_over_two_devices_equals_one_device():
    one, two = _run_sharded(1), _run_sharded(2)
    assert one["seen"] == 2 and one["devices"] == 1 and two["devices"] == 2
    # the carry leaves each chunk sharded as it entered: later chunks reuse the compiled loop
    assert one["compiles"] == 1 and two["compiles"] == 1
    for name in ("x", "fh", "fu"):
        np.testing.assert_array_equal(np.array(one[name]), np.array(two[name]))
    # ...and the chunked, sharded, padded batch equals a plain vmapped run here
    np.testing.assert_array_equal(np.array(two["x"]), _plain_batch().x)


def test_wide_vectors_change_no_bit():
    # runtime.configure asks XLA:CPU for 512-bit vectors on AVX-512 hosts: the same
    # elementwise arithmetic per lane, so the numbers must not move.
    wide, plain = _run_sharded(2, 512), _plain_batch()
    for name in ("x", "fh", "fu"):
        np.testing.assert_array_equal(np.array(wide[name]), getattr(plain, name))


def test_per_device_batch_is_padded_to_whole_vectors():
    from armimp_jax.sweep import padded_batch_size

    assert padded_batch_size(24, 2, 8) == 32  # 12 per device -> 16
    assert padded_batch_size(48, 2, 8) == 48
    assert padded_batch_size(3, 2, 8) == 4  # small batches: only to the device count
    assert padded_batch_size(17, 1, 8) == 24
    assert padded_batch_size(24, 2, 1) == 24
