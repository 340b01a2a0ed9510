"""Benchmark: d phi_T / d Mhat for one 50 s trial (paper settings), forward vs reverse mode.

Each (mode, RK4 kernel, checkpoint) runs in its own process: compile time apart, median of
repeats with ``block_until_ready``; peak RSS (``getrusage``, taken before anything else
is built in that process) and XLA's own temporary buffer size. Each process also times
the forward simulation (simulate + estimate + phi_T, default ``"fast"`` kernel),
alternating with its own runs, and reports the paired ratio. The gradients use
``--kernels`` (default: ``"grad"``, the kernel the tuner uses; add ``fast`` to compare) and
``--checkpoints`` (default: ``"substep"``, the tuner's; add ``period`` to compare).

    python sweeps/bench_gradient.py [--seconds 50] [--substeps 100] [--repeats 3]

The script sets XLA's code generation itself (``configure``), so it opts out of the
options that importing ``armimp_jax`` adds (``ARMIMP_JAX_XLA_DEFAULTS=0``): ``--no-hoist``
and ``--unroll-loops`` then really leave them off.

``--training-batch`` also times one gradient of ``tune_mhat.py``'s default training batch
(16 trials of 16 s at 20 substeps, nperseg 4096) with each checkpoint, on one device and
sharded over every core by ``tune.place_batch`` (theta replicated, as ``tune.tune`` does),
alternating, in one process.
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import pathlib
import resource
import statistics
import subprocess
import sys
import time

# configure() in each child sets code generation: keep the import-time options out of it
# (the children inherit this). No JAX backend starts on import, so configure() still applies.
os.environ["ARMIMP_JAX_XLA_DEFAULTS"] = "0"

# armimp_jax._model.plant.CHECKPOINTS, spelled out so that --help needs no JAX (checked in the children)
CHECKPOINTS = ("period", "substep")
MODES = ("primal", "reverse-diagonal", "reverse-full", "forward-diagonal", "forward-full")
KERNELS = ("fast", "grad", "reference")


def _check_checkpoints():
    from armimp_jax._model.plant import CHECKPOINTS as LIBRARY_CHECKPOINTS

    assert LIBRARY_CHECKPOINTS == CHECKPOINTS, (LIBRARY_CHECKPOINTS, CHECKPOINTS)


def child(mode, kernel, checkpoint, seconds, substeps, repeats, codegen):
    from armimp_jax.runtime import configure

    configure(host_devices=1, **codegen)
    _check_checkpoints()
    import jax
    import numpy as np

    from armimp_jax import Welch
    from armimp_jax.paper import tune as paper_tune
    from armimp_jax.study import tune

    welch = Welch() if seconds >= 10.24 else Welch(1024, 768)
    kind = "full" if mode.endswith("full") else "diagonal"
    theta = tune.theta_from_mhat(0.25 * np.eye(2), kind)

    def build(mode, kernel, checkpoint):
        params, f_delta = paper_tune.training_batch((2,), (1,), (0,), seconds=seconds)
        numerics = paper_tune.training_numerics(substeps, kernel=kernel, checkpoint=checkpoint)
        if mode == "primal":
            fn = jax.jit(
                lambda t, p, f: tune.batch_loss(t, p, f, parameterisation=kind, welch=welch, numerics=numerics)
            )
        else:
            fn = tune.value_and_grad_fn(parameterisation=kind, welch=welch, mode=mode.split("-")[0], numerics=numerics)
        t0 = time.perf_counter()
        compiled = fn.lower(theta, params, f_delta).compile()
        return functools.partial(compiled, theta, params, f_delta), time.perf_counter() - t0, compiled

    def timed(fn):
        t0 = time.perf_counter()
        out = jax.block_until_ready(fn())
        return time.perf_counter() - t0, out

    target, compile_s, compiled = build(mode, kernel, checkpoint)
    first_s, out = timed(target)
    peak_rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # before the baseline exists
    # The forward simulation (fast kernel) is timed alternately with the target in this
    # process, so that the shared host's drift hits both alike; the ratio is paired.
    baseline = target if (mode, kernel) == ("primal", "fast") else build("primal", "fast", "period")[0]
    runs, base_runs = [], []
    for _ in range(repeats):
        runs.append(timed(target)[0])
        base_runs.append(timed(baseline)[0])
    grad = None if mode == "primal" else np.asarray(out[1]).tolist()
    return dict(
        mode=mode,
        kernel=kernel,
        checkpoint=checkpoint,
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


def child_training(repeats, codegen):
    """The tuner's default training batch: one gradient per (checkpoint, placement)."""
    from armimp_jax.runtime import configure

    configure(**codegen)
    _check_checkpoints()
    import jax
    import numpy as np
    from jax.sharding import NamedSharding, PartitionSpec

    from armimp_jax import Welch
    from armimp_jax.paper import tune as paper_tune
    from armimp_jax.study import tune

    theta = tune.theta_from_mhat(0.25 * np.eye(2), "diagonal")
    # tune_mhat.py's defaults: friction 1-2 x 4 locations x 2 seeds, 16 s, 20 substeps
    batch = paper_tune.training_batch((1, 2), (1, 2, 3, 4), (0, 1), seconds=16.0)
    built = []
    for checkpoint in CHECKPOINTS:
        numerics = paper_tune.training_numerics(20, checkpoint=checkpoint)
        vg = tune.value_and_grad_fn(
            parameterisation="diagonal", welch=Welch(4096, 3072), mode="reverse", numerics=numerics
        )
        for params, f_delta, mesh in (batch + (None,), tune.place_batch(*batch)):
            t = theta if mesh is None else jax.device_put(theta, NamedSharding(mesh, PartitionSpec()))
            n = 1 if mesh is None else mesh.size
            t0 = time.perf_counter()
            compiled = vg.lower(t, params, f_delta).compile()
            compile_s = time.perf_counter() - t0
            temp = compiled.memory_analysis().temp_size_in_bytes / 2**20
            trials = int(params.q0.shape[0])
            built.append((functools.partial(compiled, t, params, f_delta), checkpoint, n, compile_s, temp, trials))
            jax.block_until_ready(built[-1][0]())
    runs = [[] for _ in built]
    for _ in range(repeats):
        for (fn, *_), times in zip(built, runs):
            t0 = time.perf_counter()
            jax.block_until_ready(fn())
            times.append(time.perf_counter() - t0)
    return [
        dict(trials=b, checkpoint=c, devices=n, compile_s=cs, xla_temp_mib=temp, run_s=statistics.median(t), runs_s=t)
        for (_, c, n, cs, temp, b), t in zip(built, runs)
    ]


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=50.0)
    ap.add_argument("--substeps", type=int, default=100)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--training-batch", action="store_true", help="also time the tuner's batch gradient")
    ap.add_argument("--child", choices=MODES + ("training",))
    ap.add_argument("--child-kernel", choices=KERNELS)
    ap.add_argument("--child-checkpoint", choices=CHECKPOINTS)
    ap.add_argument("--no-hoist", action="store_true", help="without the XLA small-loop option")
    ap.add_argument("--unroll-loops", action="store_true", help="leave LLVM's loop unrolling on (XLA's default)")
    ap.add_argument("--modes", nargs="+", choices=MODES[1:], default=list(MODES[1:]))
    ap.add_argument("--kernels", nargs="+", choices=KERNELS, default=["grad"], help="RK4 kernels of the gradients")
    ap.add_argument(
        "--checkpoints",
        nargs="+",
        choices=CHECKPOINTS,
        default=["substep"],
        help="reverse-mode tapes (Numerics.checkpoint)",
    )
    ap.add_argument("--out", type=pathlib.Path, default=pathlib.Path("results/bench"))
    args = ap.parse_args()
    codegen = dict(hoist_small_loops=not args.no_hoist, unroll_loops=args.unroll_loops)
    codegen_args = ["--no-hoist"] * args.no_hoist + ["--unroll-loops"] * args.unroll_loops
    if args.child == "training":
        print(json.dumps(child_training(args.repeats, codegen)))
        return
    if args.child:
        result = child(
            args.child, args.child_kernel, args.child_checkpoint, args.seconds, args.substeps, args.repeats, codegen
        )
        print(json.dumps(result))
        return

    def run_child(*extra):
        cmd = [sys.executable, __file__, *extra, "--repeats", str(args.repeats), *codegen_args]
        proc = subprocess.run(cmd, capture_output=True, text=True)
        if proc.returncode != 0:
            sys.exit(proc.stderr)
        return json.loads(proc.stdout.strip().splitlines()[-1])

    runs = [("primal", "fast", "period")] + [("primal", k, "period") for k in args.kernels if k != "fast"]
    runs += [(mode, k, c) for k in args.kernels for c in args.checkpoints for mode in args.modes]
    rows = []
    for mode, kernel, checkpoint in runs:
        r = run_child(
            *("--child", mode, "--child-kernel", kernel, "--child-checkpoint", checkpoint),
            *("--seconds", str(args.seconds), "--substeps", str(args.substeps)),
        )
        rows.append(r)
        print(
            f"  {mode} ({kernel} kernel, {checkpoint} checkpoint): {r['run_s']:.2f} s = {r['ratio']:.2f} x forward "
            f"simulation ({r['forward_s']:.2f} s), peak RSS {r['peak_rss_mib']:.0f} MiB",
            flush=True,
        )
    lines = [
        f"One trial, {args.seconds:g} s record, {args.substeps} substeps, friction 2, location 1, "
        f"{'without' if args.no_hoist else 'with'} the XLA small-loop option, LLVM loop unrolling "
        f"{'on' if args.unroll_loops else 'off'}:",
        "",
        "| mode | kernel | checkpoint | run s | forward simulation s (same process) | x forward simulation "
        "| compile s | XLA temp MiB | peak RSS MiB |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    lines += [
        f"| {r['mode']} | {r['kernel']} | {r['checkpoint'] if r['mode'] != 'primal' else '-'} | {r['run_s']:.2f} | "
        f"{r['forward_s']:.2f} | {r['ratio']:.2f} | {r['compile_s']:.1f} | {r['xla_temp_mib']:.0f} | "
        f"{r['peak_rss_mib']:.0f} |"
        for r in rows
    ]
    training = run_child("--child", "training") if args.training_batch else []
    if training:
        lines += [
            "",
            "Gradient of the tuner's training batch (tune_mhat.py defaults), one process, alternating:",
            "",
            "| trials | checkpoint | devices | run s | compile s | XLA temp MiB |",
            "|---|---|---|---|---|---|",
        ]
        lines += [
            f"| {r['trials']} | {r['checkpoint']} | {r['devices']} | {r['run_s']:.2f} | {r['compile_s']:.1f} | "
            f"{r['xla_temp_mib']:.0f} |"
            for r in training
        ]
    table = "\n".join(lines)
    print("\n" + table)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "bench_gradient.md").write_text(table + "\n")
    (args.out / "bench_gradient.json").write_text(
        json.dumps(dict(single_trial=rows, training_batch=training), indent=1)
    )


if __name__ == "__main__":
    main()
