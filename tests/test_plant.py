"""The plant's integration kernels (fast and grad RK4 against the reference), and the code
generation and sharding they run under."""

import functools
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
from armimp_jax import paper
from armimp_jax._plant import KERNELS, Trig, rotate

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


SHARDED = """
import json, sys
from armimp_jax.runtime import configure
n = configure(host_devices=2, **json.loads(sys.argv[2]))
import jax, numpy as np, armimp_jax as aj
from armimp_jax import _batch as sweep, paper
params = aj.stack_trials([paper.trial(c, f, 1 + f) for c in ["imbic"] for f in (0, 1, 2)])
fd = np.stack([np.asarray(aj.perturbation(jax.random.PRNGKey(i), 600, 2.25)) for i in range(3)])
mesh = sweep.make_mesh(jax.devices()[:int(sys.argv[1])])
r = sweep.simulate_batch(params, fd, numerics=aj.Numerics(substeps=5), mesh=mesh, chunk_samples=250)
compiles = sweep._chunk._cache_size()  # three chunks, one compiled loop
out = dict(devices=mesh.size, seen=n, compiles=compiles, x=r.x.tolist(), fh=r.fh.tolist(), fu=r.fu.tolist())
print(json.dumps(out))
"""


# XLA's own code generation: none of configure's XLA:CPU options.
PLAIN_XLA = dict(hoist_small_loops=False, unroll_loops=True, vector_width=None)
# What scripts run: configure's defaults.
ENTRY_POINT = {}


@functools.cache
def _run_sharded_cached(n_devices, configure_items):
    options = dict(configure_items)
    # "plain": no armimp_jax code-generation option at all, neither import's nor configure's
    plain = options == PLAIN_XLA
    env = dict(os.environ, XLA_FLAGS="", ARMIMP_JAX_XLA_DEFAULTS="0" if plain else "1")
    proc = subprocess.run(
        [sys.executable, "-c", SHARDED, str(n_devices), json.dumps(dict(configure_items))],
        capture_output=True,
        text=True,
        env=env,
        cwd=ROOT,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _run_sharded(n_devices, configure_kwargs):
    """SHARDED in a fresh process with ``configure(host_devices=2, **configure_kwargs)``."""
    return _run_sharded_cached(n_devices, tuple(sorted(configure_kwargs.items())))


def _library_batch():
    """The subprocess's batch, vmapped in this process (the code generation that importing
    armimp_jax sets up: the entry points' options without 512-bit vectors; unpadded)."""
    params = aj.stack_trials([paper.trial("imbic", f, 1 + f) for f in (0, 1, 2)])
    fd = jnp.stack([aj.perturbation(jax.random.PRNGKey(i), 600, 2.25) for i in range(3)])
    return jax.jit(jax.vmap(lambda t, f: aj.simulate(t, f, numerics=aj.Numerics(substeps=5))))(params, fd)


@pytest.mark.parametrize("codegen", [pytest.param("plain", marks=pytest.mark.slow), "entry_point"])
def test_sharded_over_two_devices_equals_one_device(codegen):
    options = PLAIN_XLA if codegen == "plain" else ENTRY_POINT
    one, two = _run_sharded(1, options), _run_sharded(2, options)
    assert one["seen"] == 2 and one["devices"] == 1 and two["devices"] == 2
    # the carry leaves each chunk sharded as it entered: later chunks reuse the compiled loop
    assert one["compiles"] == 1 and two["compiles"] == 1
    for name in ("x", "fh", "fu"):
        a, b = np.array(one[name]), np.array(two[name])
        if codegen == "entry_point":
            np.testing.assert_array_equal(a, b)
        else:  # XLA's own code generation: the partitioned program may contract FMAs differently
            scale = np.abs(b).max(axis=(1, 2), keepdims=True)
            assert np.all(np.abs(a - b) <= CODEGEN_BOUND * scale), (name, (np.abs(a - b) / scale).max())
    if codegen == "entry_point":  # ...and the chunked, sharded, padded batch equals a vmapped run here
        here = _library_batch()
        if "512" not in os.environ.get("XLA_FLAGS", "") and not aj.runtime.cpu_has_avx512():
            for name in ("x", "fh", "fu"):
                np.testing.assert_array_equal(np.array(two[name]), getattr(here, name))


def test_wide_vectors_change_no_bit():
    # 512-bit vectors (configure on AVX-512 hosts) run the same elementwise arithmetic per lane.
    wide, plain = _run_sharded(2, dict(vector_width=512)), _library_batch()
    for name in ("x", "fh", "fu"):
        np.testing.assert_array_equal(np.array(wide[name]), getattr(plain, name))


# XLA:CPU lets LLVM contract a*b + c into FMAs wherever both sit in one function. The
# small-loop kernel (one function for the whole inner loop) and loop unrolling change
# which products meet which sums, so they may move the last bits (seen on the project's
# AVX2 host: up to 3e-13 of each signal's scale over this 0.6 s record). Trajectories are
# not chaotic, so round-off does not grow into a physical difference.
CODEGEN_BOUND = 1e-11


def test_entry_point_codegen_options_agree_with_plain_xla_to_round_off():
    plain, tuned = _run_sharded(2, PLAIN_XLA), _library_batch()
    for name in ("x", "fh", "fu"):
        a, b = np.asarray(getattr(tuned, name)), np.array(plain[name])
        scale = np.abs(b).max(axis=(1, 2), keepdims=True)
        assert np.all(np.abs(a - b) <= CODEGEN_BOUND * scale), (name, (np.abs(a - b) / scale).max())


def test_configure_merges_xla_extra_options(monkeypatch):
    from armimp_jax import runtime

    monkeypatch.setenv("XLA_FLAGS", "--xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold=5")
    runtime.configure(host_devices=None, vector_width=None)
    # one flag holds all extra options; a value the caller set wins
    assert os.environ["XLA_FLAGS"] == (
        "--xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold=5,xla_cpu_disable_loop_unrolling"
    )
    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_prefer_vector_width=256")
    runtime.configure(host_devices=None, vector_width=512, unroll_loops=True)
    assert os.environ["XLA_FLAGS"] == (
        "--xla_cpu_prefer_vector_width=256 --xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold=1000000"
    )


def test_per_device_batch_is_padded_to_whole_vectors():
    from armimp_jax._batch import padded_batch_size

    assert padded_batch_size(24, 2, 8) == 32  # 12 per device -> 16
    assert padded_batch_size(24, 2, 4) == 24
    assert padded_batch_size(48, 2, 8) == 48
    assert padded_batch_size(3, 2, 4) == 8  # 2 per device -> 4
    assert padded_batch_size(3, 1, 4) == 4
    assert padded_batch_size(2, 2, 4) == 2  # one trial per device runs alone
    assert padded_batch_size(1, 1, 8) == 1
    assert padded_batch_size(17, 1, 8) == 24
    assert padded_batch_size(24, 2, 1) == 24
    assert padded_batch_size(3, 2, 1) == 4  # accelerators: only to the device count


def test_vector_lanes_follow_the_xla_vector_width(monkeypatch):
    from armimp_jax import runtime

    monkeypatch.setenv("XLA_FLAGS", "--xla_force_host_platform_device_count=2")
    assert runtime.vector_lanes() == 4  # XLA:CPU's default 256-bit vectors
    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_prefer_vector_width=512 --xla_force_host_platform_device_count=2")
    assert runtime.vector_lanes() == 8
    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_prefer_vector_width=128")
    assert runtime.vector_lanes() == 2
