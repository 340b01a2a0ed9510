"""What ``sweeps/bench_simulate.py`` measures: simulation throughput, scaling over devices,
the numba baseline, the estimator, loop unrolling, vector lanes, large batches and the
library path (the script's docstring says what each table is). The script parses its
options and sets XLA up (before JAX starts) and calls ``main``.
"""

from __future__ import annotations

import functools
import json
import os
import pathlib
import platform
import statistics
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

import armimp_jax as aj
from armimp_jax import paper, runtime

from .paired import LIBRARY_BATCH, compare_unrolling, library_path
from .tables import markdown, markdown_lanes, markdown_large, markdown_library, markdown_unrolling
from .timing import alternate, digest, save_table, serve_cases

SCRIPT = "sweeps/bench_simulate.py"  # set by main: the children run the script
CALLER_ENV: dict = {}
CALLER_XLA_FLAGS = ""
N_DEVICES = 1


def environment():
    """What the figures were measured on."""
    model = next((ln.split(":", 1)[1].strip() for ln in _cpuinfo() if ln.startswith("model name")), "")
    return dict(
        jax=jax.__version__,
        devices=N_DEVICES,
        backend=jax.default_backend(),
        device_kind=device_kind(),
        cpu=model or platform.processor() or platform.machine(),
        avx512=runtime.cpu_has_avx512(),
        vector_lanes=runtime.vector_lanes(),
        python=platform.python_version(),
        xla_flags=os.environ.get("XLA_FLAGS", ""),
    )


def device_kind():
    """The accelerator or CPU the simulations ran on, in words (``jax.devices()[0].device_kind``)."""
    return f"{jax.default_backend()}: {jax.devices()[0].device_kind} x {N_DEVICES}"


def _cpuinfo():
    try:
        return pathlib.Path("/proc/cpuinfo").read_text().splitlines()
    except OSError:
        return []


def batch_inputs(b, n, controller="imbic"):
    """``b`` trials of the paper (friction levels and locations cycled) and ``(b, n, 2)``
    seeded perturbations of level 1."""
    trials = aj.batch.stack_trials([paper.trial(controller, i % 3, 1 + i % 4) for i in range(b)])
    keys = jax.random.split(jax.random.PRNGKey(0), b)
    f_delta = jax.vmap(lambda k: aj.perturbation(k, n, paper.perturbation_peak(1)))(keys)
    return trials, f_delta


def vmapped_simulate(numerics):
    """``jax.vmap(simulate)`` with fixed numerics, jitted."""
    return jax.jit(jax.vmap(lambda t, f: aj.simulate(t, f, numerics=numerics)))


def timed(fn, repeats):
    t0 = time.perf_counter()
    jax.block_until_ready(fn())
    first = time.perf_counter() - t0
    runs = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        runs.append(time.perf_counter() - t0)
    return first, statistics.median(runs)


def build_cases(configs, seconds, substeps, *, lanes=None):
    """Compile and run once each (kernel, devices, batch) configuration: a list of
    ``(kernel, devices, batch, run, padded batch, compile s)``, ``run()`` the compiled call.
    ``lanes`` as in ``aj.batch.shard_batch`` (default: pad to whole vectors; 1: no padding)."""
    n = int(seconds * 1000)
    cases = []
    for kernel, n_dev, b in configs:
        mesh = aj.batch.make_mesh(jax.devices()[:n_dev])
        trials, f_delta = batch_inputs(b, n)
        (p_s, f_s), _ = aj.batch.shard_batch((trials, f_delta), mesh, lanes=lanes)
        t0 = time.perf_counter()
        compiled = (
            vmapped_simulate(aj.Numerics(solver=aj.solvers.RK4(kernel=kernel), substeps=substeps))
            .lower(p_s, f_s)
            .compile()
        )
        compile_s = time.perf_counter() - t0
        jax.block_until_ready(compiled(p_s, f_s))
        cases.append((kernel, n_dev, b, functools.partial(compiled, p_s, f_s), int(p_s.q0.shape[0]), compile_s))
    return cases


def bench_simulation(configs, seconds, substeps, repeats, *, lanes=None):
    """``configs``: (kernel, devices, batch) triples; ``lanes`` as in ``build_cases``.

    All configurations are compiled and run once first; then the timed repeats go round
    robin over them, so that the shared host's slow drift hits every configuration alike
    (the scaling ratios compare runs taken minutes apart otherwise). Median of repeats."""
    n = int(seconds * 1000)
    cases = build_cases(configs, seconds, substeps, lanes=lanes)
    times = alternate([case[3] for case in cases], repeats)
    rows = []
    for (kernel, n_dev, b, _, padded, compile_s), t in zip(cases, times):
        run_s = statistics.median(t)
        rows.append(
            dict(
                kernel=kernel,
                device=jax.devices()[0].device_kind,
                devices=n_dev,
                batch=b,
                padded_batch=padded,
                record_s=seconds,
                substeps=substeps,
                compile_s=compile_s,
                run_s=run_s,
                runs_s=t,
                msubsteps_per_s=b * n * substeps / run_s / 1e6,
                s_per_50s_trial=run_s / b * (50.0 / seconds),
            )
        )
        print(
            f"  sim {kernel} devices={n_dev} batch={b:3d}: {rows[-1]['msubsteps_per_s']:.2f} M substeps/s, "
            f"{rows[-1]['s_per_50s_trial']:.2f} s per 50 s trial (compile {compile_s:.1f} s)",
            flush=True,
        )
    return rows


def serve(configs, seconds, substeps):
    """Child of ``--compare-unrolling``: build the cases, print a digest of each one's
    outputs (one JSON line), then run the case named by each stdin line and print its
    seconds."""
    cases = build_cases(configs, seconds, substeps)
    digests = [digest(case[3]()) for case in cases]
    print(json.dumps(dict(digests=digests, compile_s=[c[5] for c in cases])), flush=True)
    serve_cases([c[3] for c in cases])


def serve_library(setup, seconds, substeps):
    """Child of ``--library-path``: compile and run once ``simulate_batch`` on the library
    batch, print what this process runs with (one JSON line), then run it once per stdin
    line and print its seconds."""
    trials, f_delta = batch_inputs(LIBRARY_BATCH, int(seconds * 1000))
    f_delta = np.asarray(f_delta)
    numerics = aj.Numerics(solver=aj.solvers.RK4(), substeps=substeps)  # pinned: comparable whatever the default
    run = functools.partial(aj.simulate_batch, trials, f_delta, numerics=numerics)
    t0 = time.perf_counter()
    out = jax.block_until_ready(run())  # compiles
    first_s = time.perf_counter() - t0
    flags = os.environ.get("XLA_FLAGS", "")
    ready = dict(setup=setup, devices=jax.device_count(), xla_flags=flags, lanes=runtime.vector_lanes())
    print(json.dumps(ready | dict(digest=digest(out), first_s=first_s)), flush=True)
    serve_cases([run])


def bench_grouped(b, seconds, substeps, repeats):
    """``simulate_batch`` on all devices for a large batch: in groups of at most
    ``aj.batch.MAX_PER_DEVICE`` trials per device (the default) against one group."""
    n = int(seconds * 1000)
    trials, f_delta = batch_inputs(b, n)
    f_delta = np.asarray(f_delta)
    numerics = aj.Numerics(solver=aj.solvers.RK4(), substeps=substeps)
    lanes = aj.batch.default_lanes(aj.batch.make_mesh())  # what simulate_batch pads to
    rows = []
    for cap in (aj.batch.MAX_PER_DEVICE, None):
        run = functools.partial(aj.simulate_batch, trials, f_delta, numerics=numerics, max_per_device=cap)
        first, run_s = timed(run, repeats)
        groups, size = aj.batch.batch_groups(b, N_DEVICES, max_per_device=cap, lanes=lanes)
        rows.append(
            dict(
                max_per_device=cap,
                batch=b,
                devices=N_DEVICES,
                groups=len(groups),
                group_size=size,
                first_s=first,
                run_s=run_s,
                msubsteps_per_s=b * n * substeps / run_s / 1e6,
            )
        )
        rate = rows[-1]["msubsteps_per_s"]
        print(f"  simulate_batch b={b} max_per_device={cap}: {rate:.2f} M substeps/s", flush=True)
    return rows


def bench_full_trial(b, substeps, kernel="fast"):
    """A real 50 s batch, all devices, in 5 s chunks (one compile), host copies included, one run."""
    trials, f_delta = batch_inputs(b, 50_000)
    numerics = aj.Numerics(solver=aj.solvers.RK4(kernel=kernel), substeps=substeps)
    aj.simulate_batch(trials, np.asarray(f_delta)[:, :10_000], numerics=numerics, chunk_samples=5000)  # compile
    t0 = time.perf_counter()
    aj.simulate_batch(trials, f_delta, numerics=numerics, chunk_samples=5000)
    wall = time.perf_counter() - t0
    return dict(kernel=kernel, batch=b, devices=N_DEVICES, wall_s=wall, s_per_trial=wall / b)


def bench_numba(b, seconds, substeps, repeats):
    """The hand-written scalar loop, one trajectory per core (numba prange), same inputs."""
    import numba

    from . import numba_baseline

    trials, f_delta = batch_inputs(b, int(seconds * 1000))
    f_np = np.asarray(f_delta)
    t0 = time.perf_counter()
    numba_baseline.run(trials, f_np[:, :10], substeps)
    compile_s = time.perf_counter() - t0
    runs = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        x, _ = numba_baseline.run(trials, f_np, substeps)
        runs.append(time.perf_counter() - t0)
    run_s = statistics.median(runs)
    ref = np.asarray(
        vmapped_simulate(aj.Numerics(solver=aj.solvers.RK4(kernel="reference"), substeps=substeps))(trials, f_delta).x
    )
    agree = float(np.abs(x - ref).max() / np.abs(ref - ref[:, :1]).max())
    total = b * f_np.shape[1] * substeps
    row = dict(
        threads=numba.get_num_threads(),
        batch=b,
        run_s=run_s,
        compile_s=compile_s,
        msubsteps_per_s=total / run_s / 1e6,
        rel_diff_vs_jax=agree,
    )
    print(
        f"  numba {row['threads']} threads batch={b}: {row['msubsteps_per_s']:.2f} M substeps/s "
        f"(agrees with JAX to {agree:.1e})",
        flush=True,
    )
    return row


def bench_estimator(batches, repeats, n=50_000):
    rows = []
    for b in batches:
        keys = jax.random.split(jax.random.PRNGKey(1), 3 * b)
        sig = jax.random.normal(keys[0], (b, n, 6))
        f_delta, x, fh = sig[..., :2], sig[..., 2:4], sig[..., 4:]
        ours = jax.jit(jax.vmap(lambda a, c, d: aj.estimate(a, c, d).Z))

        def ref_csd(a, c, d):  # all 36 pairs through jax.scipy.signal.csd, then the same H1 algebra
            s = jnp.concatenate([a, c, d], axis=1)
            _, g = jax.scipy.signal.csd(s[:, :, None], s[:, None, :], fs=1000.0, nperseg=8192, noverlap=6144, axis=0)
            return g[1:123]

        theirs = jax.jit(jax.vmap(ref_csd))
        for name, fn in (("armimp_jax.estimate", ours), ("jax.scipy.signal.csd (spectra only)", theirs)):
            t0 = time.perf_counter()
            compiled = fn.lower(f_delta, x, fh).compile()
            compile_s = time.perf_counter() - t0
            mem = compiled.memory_analysis()
            temp = getattr(mem, "temp_size_in_bytes", float("nan")) / 2**20
            _, run_s = timed(lambda compiled=compiled: compiled(f_delta, x, fh), repeats)
            rows.append(
                dict(
                    method=name,
                    batch=b,
                    run_s=run_s,
                    compile_s=compile_s,
                    temp_mib=temp,
                    input_mib=3 * f_delta.nbytes / 2**20,
                )
            )
            print(f"  est {name} batch={b}: {run_s:.3f} s, temp {temp:.0f} MiB (compile {compile_s:.1f} s)", flush=True)
    return rows


def run_unrolling(args, devs):
    """``--compare-unrolling``: the paired child processes, then their table."""
    batches = (4, 8) if args.quick else (8, 16, 24, 32, 48, 96)
    configs = [("fast", d, b) for d in devs for b in batches if b >= 8 * d or args.quick]
    seconds, substeps = (0.5, 10) if args.quick else (args.seconds, args.substeps)
    repeats = 1 if args.quick else args.repeats
    env = dict(os.environ, XLA_FLAGS=CALLER_XLA_FLAGS)  # the children start from the caller's flags
    rows = compare_unrolling(SCRIPT, env, configs, seconds, substeps, repeats, wide_vectors=not args.no_wide_vectors)
    table = markdown_unrolling(rows, seconds, substeps, repeats)
    print("\n" + table)
    save_table(args.out, "bench_unrolling", table, rows)


def run_lanes(args):
    """``--lanes``: unpadded batches around the vector width, one device."""
    lanes = runtime.vector_lanes()
    sizes = (1, 2, 3, 4) if args.quick else (*range(1, 2 * lanes + 1), 3 * lanes, 6 * lanes)
    seconds, substeps = (0.5, 10) if args.quick else (args.seconds, args.substeps)
    rows = bench_simulation([("fast", 1, b) for b in sizes], seconds, substeps, args.repeats, lanes=1)
    table = markdown_lanes(rows, lanes) + f"\n\n{environment()}"
    print("\n" + table)
    save_table(args.out, "bench_lanes", table, dict(env=environment(), sim=rows))


def run_large(args):
    """``--large-batch``: large batches on one device, and grouped ``simulate_batch``."""
    sizes, seconds, substeps, big = (
        ((8, 16), 0.2, 10, 8 * N_DEVICES) if args.quick else ((96, 128, 192, 256, 512), 2.0, args.substeps, 1024)
    )
    sim = bench_simulation([("fast", 1, b) for b in sizes], seconds, substeps, args.repeats)
    grouped = bench_grouped(big, seconds, substeps, args.repeats)
    table = markdown_large(sim, grouped) + f"\n\n{environment()}"
    print("\n" + table)
    save_table(args.out, "bench_large", table, dict(env=environment(), sim=sim, grouped=grouped))


def run_default(args, devs, library_settings):
    """The default run: simulation scaling, the full 50 s batch, numba, the estimator and the
    library path (``--quick``: tiny sizes of the first, numba and the library path)."""
    if not args.no_numba:
        try:
            import numba  # noqa: F401
        except ImportError:
            sys.exit("bench_simulate: error: the numba baseline needs numba (pip install -e '.[bench]'); or --no-numba")
    if args.quick:
        kernels = ("fast", "reference")
        sim = bench_simulation([(k, d, b) for k in kernels for d in devs for b in (1, 4)], 0.5, 10, 1)
        full, est = None, []
        numba_row = None if args.no_numba else bench_numba(4, 0.5, 10, 1)
    else:
        configs = [("fast", d, b) for d in devs for b in (1, 24, 48, 96, 256)]
        configs += [("reference", d, 24) for d in devs]
        sim = bench_simulation(configs, args.seconds, args.substeps, args.repeats)
        full = [bench_full_trial(48, args.substeps, "fast")]
        numba_row = None if args.no_numba else bench_numba(24, 2.0, args.substeps, args.repeats)
        est = bench_estimator([24, 96], args.repeats)
    library = library_path(SCRIPT, CALLER_ENV, *library_settings)
    env = environment()
    table = markdown(sim, full, est, numba_row, library, library_settings[2], device=device_kind())
    print("\n" + table + f"\n\n{env}")
    record = dict(env=env, sim=sim, full=full, numba=numba_row, est=est, library=library)
    save_table(args.out, "bench_simulate", table + f"\n\n{env}", record)


def main(args, *, script: str, caller_env: dict, n_devices: int):
    """Run the benchmark ``args`` (``bench_simulate.py``'s options) asks for; ``script`` is the
    script's path (the child processes run it), ``caller_env`` the environment it was started
    with, ``n_devices`` the devices its set-up gave JAX."""
    global SCRIPT, CALLER_ENV, CALLER_XLA_FLAGS, N_DEVICES
    SCRIPT, CALLER_ENV, N_DEVICES = script, dict(caller_env), n_devices
    CALLER_XLA_FLAGS = CALLER_ENV.get("XLA_FLAGS", "")
    if args.serve:
        return serve([tuple(c) for c in json.loads(args.serve)], args.seconds, args.substeps)
    if args.library_child:
        return serve_library(args.library_child, args.seconds, args.substeps)
    args.out.mkdir(parents=True, exist_ok=True)
    devs = sorted({1, N_DEVICES})
    if args.compare_unrolling:
        return run_unrolling(args, devs)
    if args.lanes:
        return run_lanes(args)
    if args.large_batch:
        return run_large(args)
    # --library-path: the library batch at the requested sizes (--quick: short records, few substeps)
    library_settings = (0.5, 10, 1) if args.quick else (args.seconds, args.substeps, args.repeats)
    if args.library_path:
        rows = library_path(SCRIPT, CALLER_ENV, *library_settings)
        table = markdown_library(rows, library_settings[2]) + f"\n\n{environment()}"
        print("\n" + table)
        save_table(args.out, "bench_library", table, dict(env=environment(), library=rows))
        return None
    return run_default(args, devs, library_settings)
