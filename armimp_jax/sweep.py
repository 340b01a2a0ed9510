"""Batches of trials: the simulate -> estimate -> accuracy pipeline, vmapped and sharded.

A batch is stacked ``TrialParams`` (``stack_trials``) plus stacked perturbations
``(B, N, 2)``. The batch axis is padded to a multiple of the device count and sharded
over a one-axis ``Mesh`` (``"batch"``): on a CPU split by ``runtime.configure`` that uses
every core; the same code shards across GPUs, or across hosts after
``jax.distributed.initialize()`` (arrays are built with ``jax.make_array_from_callback``,
so each process materialises only its own shards). Long records run in chunks of the
outer scan, so callers can show progress; chaining chunks gives the same numbers as one
call of ``simulate``.
"""

from __future__ import annotations

import functools
import math
import time
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.experimental import multihost_utils
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P

from .arm import impedance_response
from .estimate import Estimate, check_welch, estimate
from .metrics import impedance_error
from .simulate import SimResult, TrialParams, simulate_chunk, simulate_init
from .tables import ESTIMATION_FMAX, SAMPLE_RATE, WELCH_NOVERLAP, WELCH_NPERSEG


class Welch(NamedTuple):
    """Welch settings (static): segment, overlap, highest frequency [Hz], sample rate [Hz]."""

    nperseg: int = WELCH_NPERSEG
    noverlap: int = WELCH_NOVERLAP
    fmax: float = ESTIMATION_FMAX
    fs: float = SAMPLE_RATE

    def check(self, n_samples: int) -> None:
        check_welch(n_samples, fs=self.fs, nperseg=self.nperseg, noverlap=self.noverlap, fmax=self.fmax)


class TrialOutcome(NamedTuple):
    """Per-trial result of the pipeline: ``phi_T`` [N/m], ``phi_ij`` ``(2, 2)`` [N/m], the max
    input coherence over ``0 < f <= fmax``, the divergence flag and step, and the estimate."""

    phi_T: jnp.ndarray
    phi_ij: jnp.ndarray
    input_coherence: jnp.ndarray
    diverged: jnp.ndarray
    diverged_at: jnp.ndarray
    estimate: Estimate


def assess(params: TrialParams, f_delta, sim: SimResult, welch: Welch = Welch()) -> TrialOutcome:
    """Estimate the impedance from a simulated record and score it against the trial's arm."""
    est = estimate(f_delta, sim.x, sim.fh, fs=welch.fs, nperseg=welch.nperseg, noverlap=welch.noverlap, fmax=welch.fmax)
    phi_t, phi_ij = impedance_error(est.Z, impedance_response(params.arm, est.f))
    return TrialOutcome(phi_t, phi_ij, jnp.max(est.coh_inputs), sim.diverged, sim.diverged_at, est)


def make_mesh(devices=None) -> Mesh:
    """A one-axis mesh named ``"batch"`` over ``devices`` (default: all of ``jax.devices()``)."""
    return Mesh(np.asarray(jax.devices() if devices is None else devices), ("batch",))


def _batch_size(tree) -> int:
    sizes = {leaf.shape[0] for leaf in jax.tree.leaves(tree)}
    if len(sizes) != 1:
        raise ValueError(f"inconsistent batch sizes {sorted(sizes)}: stack params and perturbations alike")
    return sizes.pop()


# float64 lanes of one AVX-512 vector. XLA:CPU handles a per-device batch that is not a
# multiple of it badly: 12 trials per device run 2.5x slower than 16 (bench_simulate.py).
CPU_LANES = 8


def padded_batch_size(b: int, n_devices: int, lanes: int = 1) -> int:
    """The batch size ``shard_batch`` pads ``b`` to: a multiple of ``n_devices`` whose share
    per device is, when it exceeds ``lanes``, also a multiple of ``lanes``."""
    per_device = math.ceil(b / n_devices)
    if per_device > lanes:
        per_device = math.ceil(per_device / lanes) * lanes
    return per_device * n_devices


def default_lanes(mesh: Mesh) -> int:
    """``CPU_LANES`` on a CPU mesh, else 1 (accelerators need no padding)."""
    return CPU_LANES if mesh.devices.flat[0].platform == "cpu" else 1


def shard_batch(tree, mesh: Mesh, *, lanes: int | None = None):
    """Pad the leading (batch) axis (repeating the last trial) to ``padded_batch_size`` and
    place it sharded over the mesh. ``lanes`` defaults to ``default_lanes(mesh)``.
    Returns ``(sharded tree, original size)``; drop the padding with ``to_host``."""
    b = _batch_size(tree)
    padded = padded_batch_size(b, mesh.size, default_lanes(mesh) if lanes is None else lanes)

    def place(leaf):
        host = np.asarray(leaf)
        if padded != b:
            host = np.concatenate([host, np.repeat(host[-1:], padded - b, axis=0)])
        spec = P("batch", *([None] * (host.ndim - 1)))
        return jax.make_array_from_callback(host.shape, NamedSharding(mesh, spec), lambda idx: host[idx])

    return jax.tree.map(place, tree), b


def to_host(tree, size: int | None = None):
    """Gather a (possibly sharded, possibly multi-host) batch to NumPy, trimmed to ``size``."""
    if jax.process_count() > 1:
        tree = multihost_utils.process_allgather(tree, tiled=True)
    return jax.tree.map(lambda a: np.asarray(a)[:size], tree)


_chunk = jax.jit(jax.vmap(simulate_chunk))


@functools.partial(jax.jit, static_argnums=1)
def _init(params: TrialParams, sharding: NamedSharding):
    # Constrained like the carry that _chunk returns: otherwise XLA replicates the
    # constant leaves and the second chunk compiles the loop a second time.
    return jax.lax.with_sharding_constraint(jax.vmap(simulate_init)(params), sharding)


def simulate_batch(
    params: TrialParams,
    f_delta,
    *,
    mesh: Mesh | None = None,
    chunk_samples: int | None = None,
    progress: Callable[[int, int, float], None] | None = None,
) -> SimResult:
    """``jax.vmap(simulate)`` over a batch, sharded over ``mesh``, run in chunks.

    Args:
        params: stacked ``TrialParams`` (leading axis ``B``).
        f_delta: ``(B, N, 2)`` perturbations [N].
        chunk_samples: samples per compiled chunk (default: all at once). The record is
            zero-padded to a whole number of chunks (after its end, so nothing changes).
            At most two chunks of perturbation and output live on the devices at a
            time: each chunk's output is copied to the host while the next one runs
            (in a single-process run; across hosts the gather waits for it).
        progress: called as ``progress(done_samples, total_samples, elapsed_s)`` after
            every chunk.

    Returns the ``SimResult`` of the batch as NumPy arrays (``(B, N, 2)`` fields).
    """
    mesh = make_mesh() if mesh is None else mesh
    f_delta = np.asarray(f_delta)
    if f_delta.ndim != 3 or f_delta.shape[2] != 2:
        raise ValueError(f"f_delta must have shape (B, N, 2), got {f_delta.shape}")
    n = f_delta.shape[1]
    if n < 1:
        raise ValueError(f"f_delta must hold at least one sample per trial, got shape {f_delta.shape}")
    chunk = n if chunk_samples is None else max(1, min(int(chunk_samples), n))
    n_chunks = math.ceil(n / chunk)
    f_padded = np.concatenate([f_delta, np.zeros((f_delta.shape[0], n_chunks * chunk - n, 2))], axis=1)
    params_s, b = shard_batch(params, mesh)
    carry = _init(params_s, NamedSharding(mesh, P("batch")))
    names = ("x", "xd", "fh", "fu", "q", "z")
    fields = {name: np.empty((b, n, 2)) for name in names}  # filled chunk by chunk, no concatenation
    start, running = time.perf_counter(), None

    def collect(i, out):
        host = to_host(out, b)
        lo, hi = i * chunk, min((i + 1) * chunk, n)
        for name in names:
            fields[name][:, lo:hi] = getattr(host, name)[:, : hi - lo]
        if progress is not None:
            progress(hi, n, time.perf_counter() - start)
        return host

    for i in range(n_chunks):
        f_i, _ = shard_batch(f_padded[:, i * chunk : (i + 1) * chunk], mesh)
        carry, out = _chunk(params_s, carry, f_i)  # dispatched asynchronously
        if running is not None:
            collect(*running)
        running = (i, out)
    last = collect(*running)
    # diverged_at is sticky across chunks; a blow-up inside the zero padding does not count
    first = np.where(last.diverged_at > n, -1, last.diverged_at)
    return SimResult(**fields, diverged=first >= 0, diverged_at=first)


_assess = jax.jit(jax.vmap(assess, in_axes=(0, 0, 0, None)), static_argnums=3)


def assess_batch(
    params: TrialParams, f_delta, sim: SimResult, welch: Welch = Welch(), *, mesh: Mesh | None = None
) -> TrialOutcome:
    """``assess`` over a batch (NumPy in, NumPy out), sharded like ``simulate_batch``."""
    mesh = make_mesh() if mesh is None else mesh
    welch.check(np.shape(f_delta)[1])
    (p, f, s), b = shard_batch((params, np.asarray(f_delta), sim), mesh)
    return to_host(_assess(p, f, s, welch), b)
