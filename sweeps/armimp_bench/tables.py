"""The Markdown tables of ``bench_simulate.py``, kept apart from the measuring."""

from __future__ import annotations

import armimp_jax as aj

from .timing import markdown_head, markdown_table


def markdown_unrolling(rows, seconds, substeps, repeats):
    caption = (
        f"LLVM loop unrolling on (XLA default) vs off (`configure` default): {seconds:g} s records, "
        f"{substeps} substeps, median of {repeats}, alternating between the two processes."
    )
    columns = ("kernel", "devices", "batch", "M substeps/s, unrolled", "M substeps/s, not unrolled", "speed-up")
    cells = [
        (r["kernel"], r["devices"], r["batch"], f"{r['msubsteps_per_s_unrolled']:.2f}")
        + (f"{r['msubsteps_per_s_not_unrolled']:.2f}", f"{r['speedup']:.2f}x", "yes" if r["same_bits"] else "no")
        for r in rows
    ]
    return markdown_table(caption, columns + ("same bits",), cells)


HOW = {  # the processes of --library-path, in words
    "library": "library: the README's `aj.runtime.configure()` (one device)",
    "configured": "configured: `runtime.configure(host_devices=1)`",
    "plain": "plain XLA: float64 only, nothing configured",
}


def markdown_library(rows, repeats):
    r0 = rows[0]
    caption = (
        f"Library path: `aj.simulate_batch(trials, f_delta, numerics=aj.Numerics(solver=aj.solvers.RK4(), "
        f"substeps={r0['substeps']}))`, "
        f"{r0['batch']} IMBIC trials of {r0['record_s']:g} s, one device, compile excluded, median of {repeats}, "
        "alternating between three processes:"
    )
    columns = ("process", "XLA:CPU code generation", "devices", "M substeps/s", "vs configured")
    cells = [
        (HOW[r["setup"]], r["codegen"], r["devices"], f"{r['msubsteps_per_s']:.2f}", f"{r['vs_configured']:.2f}x")
        + ("yes" if r["same_bits_as_configured"] else "no",)
        for r in rows
    ]
    return markdown_table(caption, columns + ("same bits as configured",), cells)


def markdown_lanes(rows, lanes):
    """Unpadded batches on one device, and what padding each to ``aj.batch.padded_batch_size``
    would deliver (the padded batch's rate times the real share), where that size was run."""
    rate = {r["batch"]: r["msubsteps_per_s"] for r in rows}
    lines = [
        f"One device, unpadded batches ({lanes} float64 lanes per vector); 'padded' is the measured rate of "
        "the padded batch times its share of real trials:",
        "",
        *markdown_head("batch", "M substeps/s", "padded to", "M real substeps/s padded"),
    ]
    for r in rows:
        p = aj.batch.padded_batch_size(r["batch"], 1, lanes)
        padded = f"{rate[p] * r['batch'] / p:.2f}" if p in rate else "-"
        lines.append(f"| {r['batch']} | {r['msubsteps_per_s']:.2f} | {p} | {padded} |")
    return "\n".join(lines)


def markdown_large(sim, grouped):
    lines = markdown_head("batch on one device", "M substeps/s", "compile s")
    lines += [f"| {r['batch']} | {r['msubsteps_per_s']:.2f} | {r['compile_s']:.1f} |" for r in sim]
    lines += [
        "",
        *markdown_head("`simulate_batch`", "batch", "devices", "groups x padded size", "M substeps/s"),
    ]
    lines += [
        f"| max_per_device={r['max_per_device']} | {r['batch']} | {r['devices']} | {r['groups']} x {r['group_size']} | "
        f"{r['msubsteps_per_s']:.2f} |"
        for r in grouped
    ]
    return "\n".join(lines)


def markdown(sim, full, est, numba_row=None, library=None, library_repeats=None, *, device: str):
    lines = [
        f"Simulation on {device} (RK4, {sim[0]['substeps']} substeps, {sim[0]['record_s']:g} s records):",
        "",
        *markdown_head(
            *("kernel", "devices", "batch (padded)", "M substeps/s", "s per 50 s trial (from 5 s)", "compile s")
        ),
    ]
    lines += [
        f"| {r['kernel']} | {r['devices']} | {r['batch']} ({r['padded_batch']}) | {r['msubsteps_per_s']:.2f} | "
        f"{r['s_per_50s_trial']:.3f} | {r['compile_s']:.1f} |"
        for r in sim
    ]
    by = {(r["kernel"], r["devices"], r["batch"]): r["msubsteps_per_s"] for r in sim}
    for kernel in ("fast",):
        scal = [
            f"batch {b}: {by[(kernel, 2, b)] / by[(kernel, 1, b)]:.2f}x"
            for (k, d, b) in by
            if k == kernel and d == 1 and (kernel, 2, b) in by
        ]
        if scal:
            lines += ["", f"Scaling from 1 to 2 devices ({kernel} kernel): " + ", ".join(scal) + "."]
    if numba_row:
        best = max((v for (k, d, b), v in by.items() if k == "fast" and (b >= 24 or len(by) < 9)), default=0.0)
        lines += [
            "",
            f"numba baseline ({numba_row['threads']} threads, one trajectory per core, batch "
            f"{numba_row['batch']}): {numba_row['msubsteps_per_s']:.2f} M substeps/s; best JAX at batch >= 24 "
            f"is {best / numba_row['msubsteps_per_s']:.1f}x that (fast kernel). numba agrees with JAX to "
            f"{numba_row['rel_diff_vs_jax']:.1e} (relative, x).",
        ]
    for f in full or []:
        lines += [
            "",
            f"Measured 50 s batch ({f['kernel']} kernel): {f['batch']} trials on {f['devices']} device(s) in "
            f"{f['wall_s']:.1f} s = **{f['s_per_trial']:.2f} s per 50 s trial**.",
        ]
    lines += ["", *markdown_head("estimator (50 s records)", "batch", "run s", "XLA temp MiB", "inputs MiB")]
    lines += [
        f"| {r['method']} | {r['batch']} | {r['run_s']:.3f} | {r['temp_mib']:.0f} | {r['input_mib']:.0f} |" for r in est
    ]
    if library:
        lines += ["", markdown_library(library, library_repeats)]
    return "\n".join(lines)
