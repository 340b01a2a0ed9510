"""Batches of trials: the simulate -> estimate -> accuracy pipeline, vmapped and sharded.

A batch is stacked trials (``stack_trials``) plus stacked perturbations
``(B, N, 2)``. The batch axis is padded to a multiple of the device count and sharded
over a one-axis ``Mesh`` (``"batch"``): on a CPU split by ``runtime.configure`` that uses
every core; the same code shards across GPUs, or across hosts after
``jax.distributed.initialize()`` (arrays are built with ``jax.make_array_from_callback``,
so each process materialises only its own shards). Long records run in chunks of the
outer scan, so callers can show progress; chaining chunks gives the same numbers as one
call of ``simulate``.
"""

from __future__ import annotations

import dataclasses
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

from ._checks import check_int, check_key
from ._estimation.ensemble import Ensemble
from ._estimation.estimate import Estimate, estimate
from ._estimation.metrics import impedance_error
from ._estimation.welch import Welch
from ._model.arm import impedance_response
from ._simulate import SimResult, Trial, simulate_chunk, simulate_init
from ._solver.numerics import Numerics
from .runtime import vector_lanes


class TrialOutcome(NamedTuple):
    """Per-trial result of the pipeline: ``phi_T`` [N/m], ``phi_ij`` ``(2, 2)`` [N/m], the max
    input coherence over ``0 < f <= fmax``, the divergence flag and step, and the estimate."""

    phi_T: jnp.ndarray
    phi_ij: jnp.ndarray
    input_coherence: jnp.ndarray
    diverged: jnp.ndarray
    diverged_at: jnp.ndarray
    estimate: Estimate


def assess(trial: Trial, f_delta, sim: SimResult, welch: Welch = Welch()) -> TrialOutcome:
    """Estimate the impedance from a simulated record and score it against the trial's arm
    (single trial; vmap it, or use ``assess_batch``)."""
    est = estimate(f_delta, sim.x, sim.fh, errors=True, **welch._asdict())
    phi_t, phi_ij = impedance_error(est.Z, impedance_response(trial.arm, est.f))
    return TrialOutcome(phi_t, phi_ij, jnp.max(est.coh_inputs), sim.diverged, sim.diverged_at, est)


def make_mesh(devices=None) -> Mesh:
    """A one-axis mesh named ``"batch"`` over ``devices`` (default: all of ``jax.devices()``)."""
    return Mesh(np.asarray(jax.devices() if devices is None else devices), ("batch",))


def _batch_size(tree) -> int:
    sizes = {leaf.shape[0] for leaf in jax.tree.leaves(tree)}
    if len(sizes) != 1:
        raise ValueError(f"inconsistent batch sizes {sorted(sizes)}: stack params and perturbations alike")
    return sizes.pop()


def padded_batch_size(b: int, n_devices: int, lanes: int = 1) -> int:
    """The batch size ``shard_batch`` pads ``b`` to: a multiple of ``n_devices`` whose share
    per device is, when it exceeds one trial, also a multiple of ``lanes``."""
    per_device = math.ceil(b / n_devices)
    if per_device > 1:
        per_device = math.ceil(per_device / lanes) * lanes
    return per_device * n_devices


def default_lanes(mesh: Mesh) -> int:
    """float64 lanes of one SIMD vector (``runtime.vector_lanes``) on a CPU mesh, else 1
    (accelerators need no padding).

    XLA:CPU runs a per-device batch that is not a whole number of vectors as scalar code,
    so a few trials padded to a vector finish sooner than alone; one trial alone is as fast
    as padded (``sweeps/bench_simulate.py --lanes``)."""
    return vector_lanes() if mesh.devices.flat[0].platform == "cpu" else 1


def shard_batch(tree, mesh: Mesh, *, lanes: int | None = None, size: int | None = None):
    """Pad the leading (batch) axis (repeating the last trial) and place it sharded over the
    mesh. The padded size is ``size`` if given (at least the batch, a multiple of the mesh
    size), else ``padded_batch_size`` with ``lanes`` (default ``default_lanes(mesh)``).
    Returns ``(sharded tree, original size)``; drop the padding with ``to_host``."""
    b = _batch_size(tree)
    padded = padded_batch_size(b, mesh.size, default_lanes(mesh) if lanes is None else lanes) if size is None else size
    if padded < b or padded % mesh.size:
        raise ValueError(f"size must be >= the batch ({b}) and a multiple of the {mesh.size} devices, got {padded}")

    def place(leaf):
        host = np.asarray(leaf)
        if padded != b:
            host = np.concatenate([host, np.repeat(host[-1:], padded - b, axis=0)])
        spec = P("batch", *([None] * (host.ndim - 1)))
        return jax.make_array_from_callback(host.shape, NamedSharding(mesh, spec), lambda idx: host[idx])

    return jax.tree.map(place, tree), b


# Trials per device beyond which a batch runs as several groups, one after another, so
# that the loop's working set (a few dozen (B,) arrays) stays in cache; it also bounds the
# estimator's memory (sweeps/bench_simulate.py --large-batch).
MAX_PER_DEVICE = 128


def batch_groups(b: int, n_devices: int, *, max_per_device: int | None = MAX_PER_DEVICE, lanes: int = 1):
    """Split ``b`` trials into the fewest equal groups of at most ``max_per_device`` per
    device (``None``: one group). Returns ``([(lo, hi), ...], size)``: each group's
    trials and the size every group is padded to (``padded_batch_size``), so that all
    groups run one compiled program."""
    if max_per_device is not None and max_per_device < 1:
        raise ValueError(f"max_per_device must be a positive number of trials or None, got {max_per_device}")
    n_groups = 1 if max_per_device is None else math.ceil(b / (max_per_device * n_devices))
    per_group = math.ceil(b / n_groups)
    return [(lo, min(lo + per_group, b)) for lo in range(0, b, per_group)], padded_batch_size(
        per_group, n_devices, lanes
    )


def _rows(tree, lo: int, hi: int):
    return jax.tree.map(lambda a: np.asarray(a)[lo:hi], tree)


def to_host(tree, size: int | None = None):
    """Gather a (possibly sharded, possibly multi-host) batch to NumPy, trimmed to ``size``."""
    if jax.process_count() > 1:
        tree = multihost_utils.process_allgather(tree, tiled=True)
    return jax.tree.map(lambda a: np.asarray(a)[:size], tree)


@functools.partial(jax.jit, static_argnames="numerics")
def _chunk(trials: Trial, carry, f_delta, keys, numerics: Numerics):
    def one(trial, c, f, key):
        return simulate_chunk(trial, c, f, key=key, numerics=numerics)

    return jax.vmap(one)(trials, carry, f_delta, keys)


_vinit = jax.jit(jax.vmap(simulate_init))


def _init(trials: Trial, sharding: NamedSharding):
    # Placed like the carry that _chunk returns: otherwise XLA replicates the constant
    # leaves and the second chunk compiles the loop a second time.
    return jax.device_put(_vinit(trials), sharding)


def _key_data(keys, b: int):
    """Raw ``uint32`` key data ``(B, 2)`` (typed keys are unwrapped), or None."""
    if keys is None:
        return None
    keys = jnp.asarray(keys)
    if jnp.issubdtype(keys.dtype, jax.dtypes.prng_key):
        keys = jax.random.key_data(keys)
    keys = np.asarray(keys)
    if keys.shape[0] != b:
        raise ValueError(f"keys must hold one key per trial ({b}), got shape {keys.shape}")
    return keys


def _check_batch(trials: Trial, f_delta) -> np.ndarray:
    """``f_delta`` as a host ``(B, N, 2)`` array; one-line errors for what cannot be a batch."""
    if not isinstance(trials, Trial):
        raise ValueError(f"trials must be stacked Trial values (stack_trials), got {type(trials).__name__}")
    f_delta = np.asarray(f_delta)
    if f_delta.ndim != 3 or f_delta.shape[2] != 2:
        raise ValueError(f"f_delta must have shape (B, N, 2), got {f_delta.shape}")
    if f_delta.shape[1] < 1:
        raise ValueError(f"f_delta must hold at least one sample per trial, got shape {f_delta.shape}")
    return f_delta


def simulate_batch(
    trials: Trial,
    f_delta,
    *,
    keys=None,
    numerics: Numerics | None = None,
    mesh: Mesh | None = None,
    chunk_samples: int | None = None,
    max_per_device: int | None = MAX_PER_DEVICE,
    progress: Callable[[int, int, float], None] | None = None,
) -> SimResult:
    """``jax.vmap(simulate)`` over a batch, sharded over ``mesh``, in groups and chunks: the
    library's way to run many trials (compiled once per batch shape, every device used).

    Args:
        trials: stacked trials (``stack_trials``, leading axis ``B``).
        f_delta: ``(B, N, 2)`` perturbations [N].
        keys: ``(B,)`` keys (``jax.random.split``) for sensor noise, when the trials draw it.
        numerics: ``Numerics(...)`` of every trial (default ``Numerics()``).
        chunk_samples: samples per compiled chunk (default: all at once). The record is
            zero-padded to a whole number of chunks (after its end, so nothing changes).
            At most two chunks of perturbation and output live on the devices at a
            time: each chunk's output is copied to the host while the next one runs
            (in a single-process run; across hosts the gather waits for it).
        max_per_device: a batch with more trials per device runs as equal groups, one
            after another (``batch_groups``; ``None``: one group). With the default
            ``"fast"`` kernel a trial's numbers do not depend on its group.
        progress: called as ``progress(done, total, elapsed_s)`` after every chunk, with
            ``done`` and ``total`` in trial samples (trials times samples).

    Returns the ``SimResult`` of the batch as NumPy arrays (``(B, N, 2)`` fields).
    """
    mesh = make_mesh() if mesh is None else mesh
    numerics = Numerics() if numerics is None else numerics
    f_delta = _check_batch(trials, f_delta)
    b, n = f_delta.shape[:2]
    chunk = n if chunk_samples is None else max(1, min(int(chunk_samples), n))
    n_chunks = math.ceil(n / chunk)
    f_padded = np.concatenate([f_delta, np.zeros((b, n_chunks * chunk - n, 2))], axis=1)
    keys = _key_data(keys, b)
    groups, size = batch_groups(b, mesh.size, max_per_device=max_per_device, lanes=default_lanes(mesh))
    names = ("x", "xd", "fh", "fu", "q", "z")
    fields = {name: np.empty((b, n, 2)) for name in names}  # filled chunk by chunk, no concatenation
    diverged_at = np.empty(b, dtype=np.int32)
    start, running, done = time.perf_counter(), None, 0
    carry_sharding = NamedSharding(mesh, P("batch"))

    def collect(lo, hi, i, out):
        nonlocal done
        host = to_host(out, hi - lo)
        s_lo, s_hi = i * chunk, min((i + 1) * chunk, n)
        for name in names:
            fields[name][lo:hi, s_lo:s_hi] = getattr(host, name)[:, : s_hi - s_lo]
        if i == n_chunks - 1:
            diverged_at[lo:hi] = host.diverged_at
        done += (hi - lo) * (s_hi - s_lo)
        if progress is not None:
            progress(done, b * n, time.perf_counter() - start)

    for lo, hi in groups:
        trials_s, _ = shard_batch(_rows(trials, lo, hi), mesh, size=size)
        keys_s = None if keys is None else shard_batch(keys[lo:hi], mesh, size=size)[0]
        carry = _init(trials_s, carry_sharding)
        for i in range(n_chunks):
            f_i, _ = shard_batch(f_padded[lo:hi, i * chunk : (i + 1) * chunk], mesh, size=size)
            carry, out = _chunk(trials_s, carry, f_i, keys_s, numerics)  # dispatched asynchronously
            # XLA may label a carry leaf replicated on a one-device mesh: relabel it (free) so
            # that the next chunk hits the same compiled program.
            carry = jax.device_put(carry, carry_sharding)
            if running is not None:
                collect(*running)
            running = (lo, hi, i, out)
    collect(*running)
    # diverged_at is sticky across chunks; a blow-up inside the zero padding does not count
    first = np.where(diverged_at > n, -1, diverged_at)
    return SimResult(**fields, diverged=first >= 0, diverged_at=first)


_assess = jax.jit(jax.vmap(assess, in_axes=(0, 0, 0, None)), static_argnums=3)


def assess_batch(
    trials: Trial,
    f_delta,
    sim: SimResult,
    welch: Welch = Welch(),
    *,
    mesh: Mesh | None = None,
    max_per_device: int | None = MAX_PER_DEVICE,
) -> TrialOutcome:
    """``assess`` over a batch (NumPy in, NumPy out), sharded and grouped like ``simulate_batch``
    (groups bound the estimator's memory)."""
    mesh = make_mesh() if mesh is None else mesh
    welch.check(np.shape(f_delta)[1])
    groups, size = batch_groups(_batch_size(f_delta), mesh.size, max_per_device=max_per_device)
    outcomes = []
    for lo, hi in groups:
        (p, f, s), _ = shard_batch(_rows((trials, f_delta, sim), lo, hi), mesh, size=size)
        outcomes.append(to_host(_assess(p, f, s, welch), hi - lo))
    return jax.tree.map(lambda *parts: np.concatenate(parts), *outcomes)


class NumericsCheck(NamedTuple):
    """What ``check_numerics`` observed: the re-run trials' ``indices`` ``(S,)``, their
    ``phi_T`` [N/m] at the batch's numerics and at ``refined``, the relative differences
    ``rel_error`` ``(S,)`` (NaN where either run diverged), their maximum over the sound
    trials ``max_rel_error`` (NaN if none is sound) and the count of ``diverged`` ones."""

    indices: np.ndarray
    phi_T: np.ndarray
    phi_T_refined: np.ndarray
    rel_error: np.ndarray
    max_rel_error: float
    diverged: int
    refined: Numerics


def refined_numerics(numerics: Numerics, factor: int = 4) -> Numerics:
    """``numerics`` with ``factor`` times the substeps (same method and kernel)."""
    return dataclasses.replace(numerics, substeps=numerics.substeps * factor)


def check_numerics(
    trials: Trial,
    f_delta,
    *,
    numerics: Numerics,
    sample: int = 4,
    refine: int = 4,
    phi_T=None,
    welch: Welch = Welch(),
    keys=None,
    mesh: Mesh | None = None,
) -> NumericsCheck:
    """Re-run ``sample`` trials of a batch at ``refine`` times the substeps and report the
    observed relative error of ``phi_T``: how far a coarse sweep is from converged.

    The trials are spread evenly over the batch (first and last included). ``phi_T``
    ``(B,)`` is the batch's own result, if at hand, with NaN for diverged trials (otherwise
    the sample is also run at ``numerics``). Costs about ``refine`` times the sample's share of the batch.
    """
    sample = check_int("sample", sample, minimum=1)
    refine = check_int("refine", refine, minimum=2)
    b = _batch_size(f_delta)
    idx = np.unique(np.linspace(0, b - 1, min(sample, b)).round().astype(int))
    sub = jax.tree.map(lambda leaf: leaf[idx], (trials, np.asarray(f_delta)))
    sub_keys = None if keys is None else keys[idx]
    fine = refined_numerics(numerics, refine)

    def run(num):
        sim = simulate_batch(*sub, keys=sub_keys, numerics=num, mesh=mesh)
        out = assess_batch(*sub, sim, welch, mesh=mesh)
        return np.where(out.diverged, np.nan, out.phi_T)

    coarse = run(numerics) if phi_T is None else np.asarray(phi_T, dtype=float)[idx]
    refined = run(fine)
    err = np.abs(coarse - refined) / np.abs(refined)
    sound = np.isfinite(err)
    return NumericsCheck(
        indices=idx,
        phi_T=coarse,
        phi_T_refined=refined,
        rel_error=err,
        max_rel_error=float(np.max(err[sound])) if sound.any() else float("nan"),
        diverged=int(np.sum(~sound)),
        refined=fine,
    )


def _ensemble_perturbations(perturbation, key, repetitions, samples, period: float) -> np.ndarray:
    """``(R, N, 2)`` [N]: a family's draws, repetition ``r`` from ``fold_in(key, r)``, or the given array."""
    if hasattr(perturbation, "signal"):
        if repetitions is None or samples is None:
            raise ValueError("simulate_ensemble: a perturbation family needs repetitions= and samples=")
        r = check_int("repetitions", repetitions, minimum=2)
        n = check_int("samples", samples, minimum=3)
        return np.stack([np.asarray(perturbation.signal(jax.random.fold_in(key, i), n, period)) for i in range(r)])
    f = np.asarray(perturbation, dtype=np.float64)
    if f.ndim == 2:
        raise ValueError(
            "simulate_ensemble: one perturbation for every repetition leaves nothing once the ensemble mean is "
            "subtracted; give one per repetition, (R, N, 2), or a family such as PaperNoise(peak=...)"
        )
    if f.ndim != 3 or f.shape[2] != 2 or f.shape[0] < 2:
        raise ValueError(f"simulate_ensemble: perturbation must be a family or (R, N, 2) with R >= 2, got {f.shape}")
    for name, value, size in (("repetitions", repetitions, f.shape[0]), ("samples", samples, f.shape[1])):
        if value is not None and value != size:
            raise ValueError(f"simulate_ensemble: {name}={value} but the perturbation array holds {size}")
    return f


def simulate_ensemble(
    trial: Trial,
    perturbation,
    *,
    key,
    repetitions: int | None = None,
    samples: int | None = None,
    numerics: Numerics | None = None,
    mesh: Mesh | None = None,
    chunk_samples: int | None = None,
    progress: Callable[[int, int, float], None] | None = None,
) -> Ensemble:
    """``R`` repetitions of one reach (one trial, moving or still), each with its own perturbation
    and its own noise: one ``simulate_batch`` of the trial repeated.

    Args:
        trial: from ``make_trial`` (typically a moving arm's).
        perturbation: a perturbation family (``PaperNoise``, ``ShapedNoise``, ``Multisine``:
            anything with ``signal(key, n, period)``), drawn once per repetition, or an array
            ``(R, N, 2)`` [N] of the repetitions' own perturbations.
        key: a ``jax.random`` key. Repetition ``r`` draws its perturbation from
            ``fold_in(k1, r)`` and its noise from ``fold_in(k2, r)`` (``k1, k2 = split(key)``), so
            more repetitions extend an ensemble without changing the first ones.
        repetitions, samples: ``R`` and ``N`` (required with a family; checked against an array).
        numerics, mesh, chunk_samples, progress: as ``simulate_batch``'s.

    Returns an ``Ensemble`` (NumPy: positions, forces and perturbations ``(R, N, 2)``, the trial,
    which repetitions diverged).
    """
    check_key(key, where="simulate_ensemble")
    if not isinstance(trial, Trial):
        raise ValueError(f"simulate_ensemble: trial must be a Trial (from make_trial), got {type(trial).__name__}")
    k_perturbation, k_noise = jax.random.split(key)
    f = _ensemble_perturbations(perturbation, k_perturbation, repetitions, samples, trial.period)
    r = f.shape[0]
    trials = jax.tree.map(lambda a: np.broadcast_to(np.asarray(a), (r, *np.shape(a))), trial)
    keys = jnp.stack([jax.random.fold_in(k_noise, i) for i in range(r)]) if trial.noisy else None
    sim = simulate_batch(
        trials, f, keys=keys, numerics=numerics, mesh=mesh, chunk_samples=chunk_samples, progress=progress
    )
    return Ensemble(x=sim.x, fh=sim.fh, f_delta=f, period=trial.period, trial=trial, diverged=sim.diverged)
