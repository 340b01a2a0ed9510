"""The parents of ``bench_simulate.py``'s paired runs: ``--compare-unrolling`` and
``--library-path`` start child processes of the script (each compiled once, with its own
XLA options), time them in alternation and gather the rows. The parent runs no JAX."""

from __future__ import annotations

import json
import statistics
import sys

from .timing import run_children

SETUPS = ("library", "configured", "plain")  # the set-ups --library-path compares, a child each
LIBRARY_BATCH = 24  # trials of --library-path


def compare_unrolling(script, env, configs, seconds, substeps, repeats, wide_vectors=True):
    """The same configurations with LLVM's loop unrolling on (XLA's default) and off
    (``configure``'s default), in two child processes of ``script`` with environment ``env``,
    alternating case by case."""
    cmd = [sys.executable, script, "--serve", json.dumps(configs), "--seconds", str(seconds)]
    cmd += ["--substeps", str(substeps)] + ([] if wide_vectors else ["--no-wide-vectors"])
    specs = {unroll: (cmd + (["--unroll-loops"] if unroll else []), env) for unroll in (True, False)}
    ready, times = run_children(specs, repeats, len(configs), what="--compare-unrolling")
    n = int(seconds * 1000)
    rows = []
    for i, (kernel, n_dev, b) in enumerate(configs):
        rate = {u: b * n * substeps / statistics.median(times[(u, i)]) / 1e6 for u in specs}
        rows.append(
            dict(
                kernel=kernel,
                devices=n_dev,
                batch=b,
                msubsteps_per_s_unrolled=rate[True],
                msubsteps_per_s_not_unrolled=rate[False],
                speedup=rate[False] / rate[True],
                same_bits=ready[True]["digests"][i] == ready[False]["digests"][i],
                compile_s_unrolled=ready[True]["compile_s"][i],
                compile_s_not_unrolled=ready[False]["compile_s"][i],
                runs_s_unrolled=times[(True, i)],
                runs_s_not_unrolled=times[(False, i)],
            )
        )
        print(
            f"  {kernel} devices={n_dev} batch={b:3d}: unrolled {rate[True]:.2f}, not unrolled {rate[False]:.2f} "
            f"M substeps/s ({rows[-1]['speedup']:.2f}x), same bits: {rows[-1]['same_bits']}",
            flush=True,
        )
    return rows


def _strip_device_count(flags):
    """``XLA_FLAGS`` without a host device count (the library path runs on one device)."""
    return " ".join(f for f in flags.split() if not f.startswith("--xla_force_host_platform_device_count"))


def _codegen(flags):
    """The XLA:CPU code-generation options in ``flags``, in words."""
    opts = ["small-loop kernel" if "xla_cpu_small_while_loop_byte_threshold" in flags else "no small-loop kernel"]
    opts.append("no LLVM unrolling" if "xla_cpu_disable_loop_unrolling" in flags else "LLVM unrolling")
    width = next((f.split("=", 1)[1] for f in flags.split() if f.startswith("--xla_cpu_prefer_vector_width=")), None)
    opts.append(f"{width}-bit vectors" if width else "default vector width")
    return ", ".join(opts)


def _library_row(setup, r, runs, rate, configured_digest, seconds, substeps):
    return dict(
        setup=setup,
        batch=LIBRARY_BATCH,
        record_s=seconds,
        substeps=substeps,
        **{k: r[k] for k in ("devices", "lanes", "xla_flags")},  # what the child ran with
        codegen=_codegen(r["xla_flags"]),
        first_s=r["first_s"],
        run_s=statistics.median(runs),
        runs_s=runs,
        msubsteps_per_s=rate[setup],
        vs_configured=rate[setup] / rate["configured"],
        same_bits_as_configured=r["digest"] == configured_digest,
    )


def library_path(script, caller_env, seconds, substeps, repeats):
    """``simulate_batch`` on one device in three child processes (library, configured, plain
    XLA) started from the caller's environment ``caller_env``, compiled once each, timed in
    alternation (so the host's drift hits all alike)."""
    base = dict(caller_env)
    base["XLA_FLAGS"] = _strip_device_count(caller_env.get("XLA_FLAGS", ""))
    base["ARMIMP_JAX_CPU_DEVICES"] = "1"  # one device each (configure's own default is one per core)
    envs = dict(library=base, configured=base, plain=base)
    cmd = [sys.executable, script, "--seconds", str(seconds), "--substeps", str(substeps), "--library-child"]
    specs = {setup: (cmd + [setup], envs[setup]) for setup in SETUPS}
    ready, times = run_children(specs, repeats, 1, what="--library-path")
    work = LIBRARY_BATCH * int(seconds * 1000) * substeps
    rate = {setup: work / statistics.median(times[(setup, 0)]) / 1e6 for setup in SETUPS}
    rows = []
    for setup in SETUPS:
        r = ready[setup]
        rows.append(_library_row(setup, r, times[(setup, 0)], rate, ready["configured"]["digest"], seconds, substeps))
        print(
            f"  {setup}: {rate[setup]:.2f} M substeps/s on {r['devices']} device(s) ({rows[-1]['codegen']}; "
            f"first call {r['first_s']:.1f} s), {rows[-1]['vs_configured']:.2f}x configured, "
            f"same bits as configured: {rows[-1]['same_bits_as_configured']}",
            flush=True,
        )
    print(f"  library/configured = {rate['library'] / rate['configured']:.2f}", flush=True)
    return rows
