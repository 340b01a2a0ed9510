"""Benchmark: d phi_T / d Mhat for one 50 s trial (paper settings), forward vs reverse mode.

Each (mode, RK4 kernel) pair runs in its own process: compile time apart, median of
repeats with ``block_until_ready``; peak RSS (``getrusage``, taken before anything else
is built in that process) and XLA's own temporary buffer size. Each process also times
the forward simulation (simulate + estimate + phi_T, default ``"fast"`` kernel),
alternating with its own runs, and reports the paired ratio. The gradients use
``--kernels`` (default: ``"grad"``, the kernel the tuner uses; add ``fast`` to compare).

    python sweeps/bench_gradient.py [--seconds 50] [--substeps 100] [--repeats 3]

``--training-batch`` also times one gradient of ``tune_mhat.py``'s default training batch
(16 trials of 16 s at 20 substeps, nperseg 4096), on one device and sharded over every
core by ``tune.place_batch``, alternating, in one process.
"""

from __future__ import annotations

import argparse
import functools
import json
import pathlib
import resource
import statistics
import subprocess
import sys
import time

MODES = ("primal", "reverse-diagonal", "reverse-full", "forward-diagonal", "forward-full")
KERNELS = ("fast", "grad", "reference")


def child(mode, kernel, seconds, substeps, repeats, hoist=True):
    from armimp_jax.runtime import configure

    configure(host_devices=1, hoist_small_loops=hoist)
    import jax
    import numpy as np

    from armimp_jax import tune
    from armimp_jax.sweep import Welch

    welch = Welch() if seconds >= 8.192 else Welch(1024, 768)
    kind = "full" if mode.endswith("full") else "diagonal"
    theta = tune.theta_from_mhat(0.25 * np.eye(2), kind)

    def build(mode, kernel):
        params, f_delta = tune.training_batch((2,), (1,), (0,), seconds=seconds, substeps=substeps, kernel=kernel)
        if mode == "primal":
            fn = jax.jit(lambda t, p, f: tune.batch_loss(t, p, f, parameterisation=kind, welch=welch))
        else:
            fn = tune.value_and_grad_fn(parameterisation=kind, welch=welch, mode=mode.split("-")[0])
        t0 = time.perf_counter()
        compiled = fn.lower(theta, params, f_delta).compile()
        return functools.partial(compiled, theta, params, f_delta), time.perf_counter() - t0, compiled

    def timed(fn):
        t0 = time.perf_counter()
        out = jax.block_until_ready(fn())
        return time.perf_counter() - t0, out

    target, compile_s, compiled = build(mode, kernel)
    first_s, out = timed(target)
    peak_rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # before the baseline exists
    # The forward simulation (fast kernel) is timed alternately with the target in this
    # process, so that the shared host's drift hits both alike; the ratio is paired.
    baseline = target if (mode, kernel) == ("primal", "fast") else build("primal", "fast")[0]
    runs, base_runs = [], []
    for _ in range(repeats):
        runs.append(timed(target)[0])
        base_runs.append(timed(baseline)[0])
    grad = None if mode == "primal" else np.asarray(out[1]).tolist()
    return dict(
        mode=mode,
        kernel=kernel,
        compile_s=compile_s,
        run_s=statistics.median(runs),
        forward_s=statistics.median(base_runs),
        ratio=statistics.median(runs) / statistics.median(base_runs),
        runs_s=runs,
        forward_runs_s=base_runs,
        xla_temp_mib=compiled.memory_analysis().temp_size_in_bytes / 2**20,
        peak_rss_mib=peak_rss,
        grad=grad,
    )


def child_training(repeats):
    from armimp_jax.runtime import configure

    configure()
    import jax
    import numpy as np

    from armimp_jax import tune
    from armimp_jax.sweep import Welch

    # tune_mhat.py's defaults: friction 1-2 x 4 locations x 2 seeds, 16 s, 20 substeps
    params, f_delta = tune.training_batch((1, 2), (1, 2, 3, 4), (0, 1), seconds=16.0, substeps=20)
    theta = tune.theta_from_mhat(0.25 * np.eye(2), "diagonal")
    vg = tune.value_and_grad_fn(parameterisation="diagonal", welch=Welch(4096, 3072), mode="reverse")
    built = []
    for placed in ((params, f_delta, 1), tune.place_batch(params, f_delta)):
        t0 = time.perf_counter()
        compiled = vg.lower(theta, *placed[:2]).compile()
        built.append((functools.partial(compiled, theta, *placed[:2]), placed[2], time.perf_counter() - t0))
        jax.block_until_ready(built[-1][0]())
    runs = [[] for _ in built]
    for _ in range(repeats):
        for (fn, _, _), times in zip(built, runs):
            t0 = time.perf_counter()
            jax.block_until_ready(fn())
            times.append(time.perf_counter() - t0)
    n_trials = int(params.q0.shape[0])
    return [
        dict(trials=n_trials, devices=n, compile_s=c, run_s=statistics.median(t), runs_s=t)
        for (_, n, c), t in zip(built, runs)
    ]


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=50.0)
    ap.add_argument("--substeps", type=int, default=100)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--training-batch", action="store_true", help="also time the tuner's batch gradient")
    ap.add_argument("--child", choices=MODES + ("training",))
    ap.add_argument("--child-kernel", choices=KERNELS)
    ap.add_argument("--no-hoist", action="store_true", help="without the XLA small-loop option")
    ap.add_argument("--modes", nargs="+", choices=MODES[1:], default=list(MODES[1:]))
    ap.add_argument("--kernels", nargs="+", choices=KERNELS, default=["grad"], help="RK4 kernels of the gradients")
    ap.add_argument("--out", type=pathlib.Path, default=pathlib.Path("results/bench"))
    args = ap.parse_args()
    if args.child == "training":
        print(json.dumps(child_training(args.repeats)))
        return
    if args.child:
        hoist = not args.no_hoist
        print(json.dumps(child(args.child, args.child_kernel, args.seconds, args.substeps, args.repeats, hoist)))
        return
    runs = [("primal", "fast")] + [("primal", k) for k in args.kernels if k != "fast"]
    runs += [(mode, k) for k in args.kernels for mode in args.modes]
    rows = []
    for mode, kernel in runs:
        proc = subprocess.run(
            [
                sys.executable,
                __file__,
                "--child",
                mode,
                "--child-kernel",
                kernel,
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
        r = rows[-1]
        print(
            f"  {mode} ({kernel} kernel): {r['run_s']:.2f} s = {r['ratio']:.2f} x forward simulation "
            f"({r['forward_s']:.2f} s), peak RSS {r['peak_rss_mib']:.0f} MiB",
            flush=True,
        )
    hoist = "without" if args.no_hoist else "with"
    lines = [
        f"One trial, {args.seconds:g} s record, {args.substeps} substeps, friction 2, location 1, "
        f"{hoist} the XLA small-loop option:",
        "",
        "| mode | kernel | run s | forward simulation s (same process) | x forward simulation | compile s "
        "| XLA temp MiB | peak RSS MiB |",
        "|---|---|---|---|---|---|---|---|",
    ]
    lines += [
        f"| {r['mode']} | {r['kernel']} | {r['run_s']:.2f} | {r['forward_s']:.2f} | {r['ratio']:.2f} | "
        f"{r['compile_s']:.1f} | {r['xla_temp_mib']:.0f} | {r['peak_rss_mib']:.0f} |"
        for r in rows
    ]
    if args.training_batch:
        proc = subprocess.run(
            [sys.executable, __file__, "--child", "training", "--repeats", str(args.repeats)],
            capture_output=True,
            text=True,
        )
        if proc.returncode != 0:
            sys.exit(proc.stderr)
        training = json.loads(proc.stdout.strip().splitlines()[-1])
        rows.append(dict(training=training))
        lines += [
            "",
            "Gradient of the tuner's training batch (tune_mhat.py defaults), one process:",
            "",
            "| trials | devices | run s | compile s |",
            "|---|---|---|---|",
        ]
        lines += [f"| {r['trials']} | {r['devices']} | {r['run_s']:.2f} | {r['compile_s']:.1f} |" for r in training]
    table = "\n".join(lines)
    print("\n" + table)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "bench_gradient.md").write_text(table + "\n")
    (args.out / "bench_gradient.json").write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
