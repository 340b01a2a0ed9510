"""Benchmark: d phi_T / d Mhat for one 50 s trial (paper settings), forward vs reverse mode.

Each mode runs in its own process (clean peak memory): compile time apart, median of
repeats with ``block_until_ready``; peak RSS from ``getrusage`` and XLA's own temporary
buffer size. Reports time relative to the forward simulation (simulate + estimate + phi_T).

    python sweeps/bench_gradient.py [--seconds 50] [--substeps 100] [--repeats 3]
"""

from __future__ import annotations

import argparse
import json
import pathlib
import resource
import statistics
import subprocess
import sys
import time

MODES = ("primal", "forward-diagonal", "forward-full", "reverse-diagonal", "reverse-full")


def child(mode, seconds, substeps, repeats, hoist=True):
    from armimp_jax.runtime import configure

    configure(host_devices=1, hoist_small_loops=hoist)
    import jax
    import numpy as np

    from armimp_jax import tune
    from armimp_jax.sweep import Welch

    params, f_delta = tune.training_batch((2,), (1,), (0,), seconds=seconds, substeps=substeps)
    welch = Welch() if seconds >= 8.192 else Welch(1024, 768)
    kind = "full" if mode.endswith("full") else "diagonal"
    theta = tune.theta_from_mhat(0.25 * np.eye(2), kind)
    if mode == "primal":
        fn = jax.jit(lambda t, p, f: tune.batch_loss(t, p, f, parameterisation=kind, welch=welch))
    else:
        fn = tune.value_and_grad_fn(parameterisation=kind, welch=welch, mode=mode.split("-")[0])
    t0 = time.perf_counter()
    compiled = fn.lower(theta, params, f_delta).compile()
    compile_s = time.perf_counter() - t0
    temp = compiled.memory_analysis().temp_size_in_bytes / 2**20
    runs = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = jax.block_until_ready(compiled(theta, params, f_delta))
        runs.append(time.perf_counter() - t0)
    grad = None if mode == "primal" else np.asarray(out[1]).tolist()
    return dict(
        mode=mode,
        compile_s=compile_s,
        run_s=statistics.median(runs),
        xla_temp_mib=temp,
        peak_rss_mib=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        grad=grad,
    )


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=50.0)
    ap.add_argument("--substeps", type=int, default=100)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--child", choices=MODES)
    ap.add_argument("--no-hoist", action="store_true", help="without the XLA small-loop option")
    ap.add_argument("--modes", nargs="+", choices=MODES, default=list(MODES))
    ap.add_argument("--out", type=pathlib.Path, default=pathlib.Path("results/bench"))
    args = ap.parse_args()
    if args.child:
        print(json.dumps(child(args.child, args.seconds, args.substeps, args.repeats, hoist=not args.no_hoist)))
        return
    rows = []
    for mode in args.modes:
        proc = subprocess.run(
            [
                sys.executable,
                __file__,
                "--child",
                mode,
                "--seconds",
                str(args.seconds),
                "--substeps",
                str(args.substeps),
                "--repeats",
                str(args.repeats),
            ]
            + (["--no-hoist"] if args.no_hoist else []),
            capture_output=True,
            text=True,
        )
        if proc.returncode != 0:
            sys.exit(proc.stderr)
        rows.append(json.loads(proc.stdout.strip().splitlines()[-1]))
        print(f"  {mode}: {rows[-1]['run_s']:.2f} s, peak RSS {rows[-1]['peak_rss_mib']:.0f} MiB", flush=True)
    primal = rows[0]["run_s"]
    hoist = "without" if args.no_hoist else "with"
    lines = [
        f"One trial, {args.seconds:g} s record, {args.substeps} substeps, friction 2, location 1, "
        f"{hoist} the XLA small-loop option:",
        "",
        "| mode | run s | x forward simulation | compile s | XLA temp MiB | peak RSS MiB |",
        "|---|---|---|---|---|---|",
    ]
    lines += [
        f"| {r['mode']} | {r['run_s']:.2f} | {r['run_s'] / primal:.2f} | {r['compile_s']:.1f} | "
        f"{r['xla_temp_mib']:.0f} | {r['peak_rss_mib']:.0f} |"
        for r in rows
    ]
    table = "\n".join(lines)
    print("\n" + table)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "bench_gradient.md").write_text(table + "\n")
    (args.out / "bench_gradient.json").write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
