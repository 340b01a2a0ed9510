"""Batches (armimp_jax._batch): sharded over devices against one device, under the entry
point's code generation and plain XLA, and padded to whole vectors."""

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
from helpers import tree_equal

import armimp_jax as aj
from armimp_jax import _batch, paper

ROOT = pathlib.Path(__file__).resolve().parents[1]


SHARDED = """
import json, sys
from armimp_jax.runtime import configure
n = configure(host_devices=2, **json.loads(sys.argv[2]))
import jax, numpy as np, armimp_jax as aj
from armimp_jax import _batch as sweep, paper
params = aj.batch.stack_trials([paper.trial(c, f, 1 + f) for c in ["imbic"] for f in (0, 1, 2)])
fd = np.stack([np.asarray(aj.perturbation(jax.random.PRNGKey(i), 600, 2.25)) for i in range(3)])
mesh = sweep.make_mesh(jax.devices()[:int(sys.argv[1])])
num = aj.Numerics(solver=aj.solvers.RK4(), substeps=5)
r = sweep.simulate_batch(params, fd, numerics=num, mesh=mesh, chunk_samples=250)
compiles = sweep._chunk._cache_size()  # three chunks, one compiled loop
out = dict(devices=mesh.size, seen=n, compiles=compiles, x=r.x.tolist(), fh=r.fh.tolist(), fu=r.fu.tolist())
if sys.argv[3] == "vmapped":  # the same batch vmapped, unpadded, in this process's code generation
    num = aj.Numerics(solver=aj.solvers.RK4(), substeps=5)
    v = jax.jit(jax.vmap(lambda t, f: aj.simulate(t, f, numerics=num)))(params, jax.numpy.asarray(fd))
    out["vmapped"] = {name: np.asarray(getattr(v, name)).tolist() for name in ("x", "fh", "fu")}
print(json.dumps(out))
"""


# XLA's own code generation: none of configure's XLA:CPU options.
PLAIN_XLA = dict(hoist_small_loops=False, unroll_loops=True, vector_width=None)
# What scripts run: configure's defaults.
ENTRY_POINT = {}


@functools.cache
def _run_sharded_cached(n_devices, configure_items, vmapped):
    # "plain": no armimp_jax code-generation option at all (importing the package sets none)
    env = dict(os.environ, XLA_FLAGS="")
    proc = subprocess.run(
        [sys.executable, "-c", SHARDED, str(n_devices), json.dumps(dict(configure_items)), vmapped],
        capture_output=True,
        text=True,
        env=env,
        cwd=ROOT,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _run_sharded(n_devices, configure_kwargs, vmapped=False):
    """SHARDED in a fresh process with ``configure(host_devices=2, **configure_kwargs)`` (and, with
    ``vmapped``, the same batch vmapped there)."""
    return _run_sharded_cached(n_devices, tuple(sorted(configure_kwargs.items())), "vmapped" if vmapped else "-")


def _library_batch():
    """The subprocess's batch, vmapped in this process (the code generation that importing
    armimp_jax sets up: the entry points' options without 512-bit vectors; unpadded)."""
    params = aj.batch.stack_trials([paper.trial("imbic", f, 1 + f) for f in (0, 1, 2)])
    fd = jnp.stack([aj.perturbation(jax.random.PRNGKey(i), 600, 2.25) for i in range(3)])
    return jax.jit(jax.vmap(lambda t, f: aj.simulate(t, f, numerics=aj.Numerics(solver=aj.solvers.RK4(), substeps=5))))(
        params, fd
    )


@pytest.mark.parametrize("codegen", [pytest.param("plain", marks=pytest.mark.slow), "entry_point"])
def test_sharded_over_two_devices_equals_one_device(codegen):
    options = PLAIN_XLA if codegen == "plain" else ENTRY_POINT
    one, two = _run_sharded(1, options), _run_sharded(2, options, vmapped=codegen == "entry_point")
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
    if codegen == "entry_point":  # ...and the chunked, sharded, padded batch equals the vmapped run
        # of the same process: on every host, whatever vector width configure chose there (512 bits on
        # AVX-512 hosts, where this process's import-time code generation would differ; that 512-bit
        # vectors change no bit is test_wide_vectors_change_no_bit's, slow)
        for name in ("x", "fh", "fu"):
            np.testing.assert_array_equal(np.array(two[name]), np.array(two["vmapped"][name]))


@pytest.mark.slow  # 512-bit vectors matter on AVX-512 hosts; the default code generation is checked fast
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


@pytest.mark.slow  # 17 s cold (the suite's budget); the sharded entry point stays fast
def test_entry_point_codegen_options_agree_with_plain_xla_to_round_off():
    plain, tuned = _run_sharded(2, PLAIN_XLA), _library_batch()
    for name in ("x", "fh", "fu"):
        a, b = np.asarray(getattr(tuned, name)), np.array(plain[name])
        scale = np.abs(b).max(axis=(1, 2), keepdims=True)
        assert np.all(np.abs(a - b) <= CODEGEN_BOUND * scale), (name, (np.abs(a - b) / scale).max())


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


@jax.jit
def _vmapped(trials, fds):
    return jax.vmap(lambda t, f: aj.simulate(t, f, numerics=aj.Numerics(solver=aj.solvers.RK4(), substeps=4)))(
        trials, fds
    )


def test_batch_groups_are_equal_and_bounded():
    assert _batch.batch_groups(5, 1, max_per_device=2, lanes=4) == ([(0, 2), (2, 4), (4, 5)], 4)
    assert _batch.batch_groups(256, 2, max_per_device=128) == ([(0, 256)], 256)
    assert _batch.batch_groups(1000, 2, max_per_device=128) == ([(0, 250), (250, 500), (500, 750), (750, 1000)], 250)
    assert _batch.batch_groups(300, 2, max_per_device=128, lanes=4) == ([(0, 150), (150, 300)], 152)
    assert _batch.batch_groups(300, 2, max_per_device=None) == ([(0, 300)], 300)
    with pytest.raises(ValueError, match="max_per_device must be a positive number of trials or None, got 0"):
        _batch.batch_groups(3, 1, max_per_device=0)


def test_grouped_chunked_batches_give_the_numbers_of_one_vmapped_batch():
    cases = [("imbic", f, loc) for f, loc in ((0, 1), (1, 2), (2, 3), (2, 4), (1, 1))]
    params = aj.batch.stack_trials([paper.trial(c, f, loc) for c, f, loc in cases])
    fd = np.stack([np.asarray(aj.perturbation(jax.random.PRNGKey(i), 300, 2.25)) for i in range(len(cases))])
    ref = jax.tree.map(np.asarray, _vmapped(params, jnp.asarray(fd)))
    seen = []
    grouped = _batch.simulate_batch(
        params,
        fd,
        numerics=aj.Numerics(solver=aj.solvers.RK4(), substeps=4),
        chunk_samples=120,
        max_per_device=2,
        progress=lambda done, total, _: seen.append((done, total)),
    )
    assert tree_equal(grouped, ref)  # on one device: three groups (2, 2, 1 trials, each padded to 4) x three chunks
    groups, _ = _batch.batch_groups(len(cases), jax.device_count(), max_per_device=2)
    assert [d for d, _ in seen] == sorted(d for d, _ in seen) and len(seen) == 3 * len(groups)
    assert seen[-1] == (5 * 300, 5 * 300)
    welch = aj.Welch(nperseg=128, noverlap=64, fmax=15.0)
    one = _batch.assess_batch(params, fd, grouped, welch, max_per_device=None)
    two = _batch.assess_batch(params, fd, grouped, welch, max_per_device=2)
    # the force's broadband excess reduces spectra over ~50 bins, which XLA vectorises by batch
    # size: the same to round-off; every other number bitwise
    np.testing.assert_allclose(two.estimate.force_excess, one.estimate.force_excess, rtol=1e-12)

    def without_excess(outcome):
        return outcome._replace(estimate=outcome.estimate._replace(force_excess=None))

    assert tree_equal(without_excess(two), without_excess(one))
