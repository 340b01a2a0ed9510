"""What ``sweeps/bench_gradient.py`` measures: a trial's gradient in each mode, kernel and
checkpoint against its forward simulation, the tuner's training batch, and forward-mode
Jacobians (the script's docstring says what each table is); each measurement runs in a
child process of the script (``main``).
"""

from __future__ import annotations

import functools
import json
import os
import resource
import statistics
import subprocess
import sys
import time

from armimp_jax.study.runs.cli import solver

from .timing import alternate, markdown_head, save_table

# aj.Numerics.CHECKPOINTS and aj.solvers.RK4.KERNELS, spelled out so that --help needs no JAX (checked in the children)
CHECKPOINTS = ("period", "substep")
MODES = ("primal", "reverse-diagonal", "reverse-full", "forward-diagonal", "forward-full")
KERNELS = ("fast", "grad", "reference")


JAC_SETTINGS = "rk4:fast:100,rk4:grad:100,ark3:fast:20,gark4:fast:4"
JAC_PARAMETERS = 16  # the arm's M, B, K (12) and tau_c, tau_s of both joints (4)


def _check_checkpoints():
    import armimp_jax as aj

    assert aj.Numerics.CHECKPOINTS == CHECKPOINTS, (aj.Numerics.CHECKPOINTS, CHECKPOINTS)
    assert set(aj.solvers.RK4.KERNELS) == set(KERNELS), (aj.solvers.RK4.KERNELS, KERNELS)


def child(mode, kernel, checkpoint, seconds, substeps, repeats, codegen):
    from armimp_jax.runtime import configure

    configure(host_devices=1, compilation_cache=False, **codegen)
    _check_checkpoints()
    import jax
    import numpy as np

    from armimp_jax import Welch
    from armimp_jax.paper import mhat_experiment as paper_tune
    from armimp_jax.study.design import tuning as tune

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

    target, compile_s, compiled = build(mode, kernel, checkpoint)
    out = jax.block_until_ready(target())  # the first run, untimed
    peak_rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # before the baseline exists
    # The forward simulation (fast kernel) is timed alternately with the target in this
    # process, so that the shared host's drift hits both alike; the ratio is paired.
    baseline = target if (mode, kernel) == ("primal", "fast") else build("primal", "fast", "period")[0]
    runs, base_runs = alternate([target, baseline], repeats)
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


def child_jacobian(setting, seconds, repeats, codegen):
    """``jax.jacfwd`` of ``(x, fh)`` with respect to 16 trial parameters against one forward
    run and 16 separate ones, one solver setting ``METHOD:KERNEL:SUBSTEPS``."""
    from armimp_jax.runtime import configure

    configure(host_devices=1, compilation_cache=False, **codegen)
    import dataclasses

    import jax
    import jax.numpy as jnp
    import numpy as np

    import armimp_jax as aj
    from armimp_jax import paper

    method, kernel, substeps = setting.split(":")
    numerics = aj.Numerics(solver=solver(method, kernel=kernel), substeps=int(substeps))
    n = int(round(seconds * 1000))
    trial = paper.trial("imbic", 2, 1)
    f_delta = jnp.asarray(aj.perturbation(jax.random.key(0), n, peak=paper.perturbation_peak(1)))
    arm, fr = trial.arm, trial.friction
    theta0 = jnp.concatenate([arm.mass.ravel(), arm.damping.ravel(), arm.stiffness.ravel(), fr.tau_c, fr.tau_s])
    assert theta0.shape == (JAC_PARAMETERS,)

    def record(theta):
        m, b, k = (theta[4 * i : 4 * i + 4].reshape(2, 2) for i in range(3))
        bristles = dict(sigma0=fr.sigma0, sigma1=fr.sigma1, sigma2=fr.sigma2, v_s=fr.v_s)
        friction = aj.LuGre(theta[12:14], theta[14:16], **bristles)
        t = dataclasses.replace(trial, arm=aj.Arm(m, b, k, arm.endpoint), friction=friction)
        sim = aj.simulate(t, f_delta, numerics=numerics)
        return sim.x, sim.fh

    def compiled(fn):
        t0 = time.perf_counter()
        out = jax.jit(fn).lower(theta0).compile()
        return out, time.perf_counter() - t0

    forward, forward_compile_s = compiled(record)
    jacobian, jacobian_compile_s = compiled(jax.jacfwd(record))
    thetas = [theta0 * (1.0 + 1e-3 * i) for i in range(JAC_PARAMETERS)]
    runs = dict(forward=lambda: forward(theta0), jacobian=lambda: jacobian(theta0))
    runs["16 forwards"] = lambda: [forward(t) for t in thetas]
    jac = jax.block_until_ready(runs["jacobian"]())
    jax.block_until_ready(runs["forward"]())
    times = dict(zip(runs, alternate(list(runs.values()), repeats)))
    med = {name: statistics.median(t) for name, t in times.items()}
    return dict(
        setting=setting,
        seconds=seconds,
        parameters=JAC_PARAMETERS,
        forward_s=med["forward"],
        jacobian_s=med["jacobian"],
        forwards_16_s=med["16 forwards"],
        jacobian_in_forwards=med["jacobian"] / med["forward"],
        runs_s=times,
        forward_compile_s=forward_compile_s,
        jacobian_compile_s=jacobian_compile_s,
        jacobian_finite=bool(all(np.all(np.isfinite(np.asarray(j))) for j in jac)),
        load=os.getloadavg(),
    )


def child_training(repeats, codegen):
    """The tuner's default training batch: one gradient per (checkpoint, placement)."""
    from armimp_jax.runtime import configure

    configure(compilation_cache=False, **codegen)
    _check_checkpoints()
    import jax
    import numpy as np
    from jax.sharding import NamedSharding, PartitionSpec

    from armimp_jax import Welch
    from armimp_jax.paper import mhat_experiment as paper_tune
    from armimp_jax.study.design import tuning as tune

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
    runs = alternate([b[0] for b in built], repeats)
    return [
        dict(trials=b, checkpoint=c, devices=n, compile_s=cs, xla_temp_mib=temp, run_s=statistics.median(t), runs_s=t)
        for (_, c, n, cs, temp, b), t in zip(built, runs)
    ]


def run_as_child(args, codegen) -> dict | list:
    """What a child process (``--child``) measures: its JSON-ready result."""
    if args.child == "training":
        return child_training(args.repeats, codegen)
    if args.child == "jacobian":
        return child_jacobian(args.child_setting, args.seconds, args.repeats, codegen)
    return child(
        args.child, args.child_kernel, args.child_checkpoint, args.seconds, args.substeps, args.repeats, codegen
    )


def main(args, *, script: str):
    """Run what ``args`` (``bench_gradient.py``'s options) asks for; children run ``script``."""
    codegen = dict(hoist_small_loops=not args.no_hoist, unroll_loops=args.unroll_loops)
    codegen_args = ["--no-hoist"] * args.no_hoist + ["--unroll-loops"] * args.unroll_loops
    if args.child:
        print(json.dumps(run_as_child(args, codegen)))
        return None

    def run_child(*extra):
        cmd = [sys.executable, script, *extra, "--repeats", str(args.repeats), *codegen_args]
        proc = subprocess.run(cmd, capture_output=True, text=True)
        if proc.returncode != 0:
            sys.exit(proc.stderr)
        return json.loads(proc.stdout.strip().splitlines()[-1])

    if args.jacobian:
        return jacobian_table(args, run_child)
    return gradient_table(args, run_child)


def gradient_table(args, run_child):
    """The default run: one child per (mode, kernel, checkpoint) and the primal baselines, the
    training batch (``--training-batch``), then the table (Markdown and JSON under ``--out``)."""
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
        *markdown_head(
            *("mode", "kernel", "checkpoint", "run s", "forward simulation s (same process)"),
            *("x forward simulation", "compile s", "XLA temp MiB", "peak RSS MiB"),
        ),
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
            *markdown_head("trials", "checkpoint", "devices", "run s", "compile s", "XLA temp MiB"),
        ]
        lines += [
            f"| {r['trials']} | {r['checkpoint']} | {r['devices']} | {r['run_s']:.2f} | {r['compile_s']:.1f} | "
            f"{r['xla_temp_mib']:.0f} |"
            for r in training
        ]
    table = "\n".join(lines)
    print("\n" + table)
    save_table(args.out, "bench_gradient", table, dict(single_trial=rows, training_batch=training))


def jacobian_table(args, run_child):
    """``--jacobian``: one child per setting, then the table (Markdown and JSON under ``--out``)."""
    rows = []
    for setting in args.jac_settings.split(","):
        r = run_child("--child", "jacobian", "--child-setting", setting, "--seconds", str(args.seconds))
        rows.append(r)
        print(
            f"  {setting}: jacfwd {r['jacobian_s']:.3f} s = {r['jacobian_in_forwards']:.2f} forwards "
            f"({r['forward_s']:.3f} s), 16 forwards {r['forwards_16_s']:.3f} s, load {r['load'][0]:.1f}",
            flush=True,
        )
    lines = [
        f"Forward-mode Jacobian of one trial's x and fh ({args.seconds:g} s record, IMBIC, friction 2, location 1) "
        f"with respect to {JAC_PARAMETERS} parameters, one device, compile excluded, median of {args.repeats}:",
        "",
        *markdown_head(
            *("solver:kernel:substeps", "forward s", "jacfwd s", "jacfwd in forwards (target <= 8)"),
            *("16 forwards s", "compile forward / jacfwd s", "load"),
        ),
    ]
    lines += [
        f"| {r['setting']} | {r['forward_s']:.3f} | {r['jacobian_s']:.3f} | {r['jacobian_in_forwards']:.2f} | "
        f"{r['forwards_16_s']:.3f} | {r['forward_compile_s']:.1f} / {r['jacobian_compile_s']:.1f} | "
        f"{r['load'][0]:.1f} |"
        for r in rows
    ]
    table = "\n".join(lines)
    print("\n" + table)
    save_table(args.out, "bench_jacobian", table, rows)
