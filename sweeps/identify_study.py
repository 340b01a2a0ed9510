"""Bias and interval coverage of the classical FRF fit against identify, over friction, controller
and acquisition, with the person's own force on (docs/identification.md, section 7).

For each acquisition (instant samples, interval means), controller (PD, IMBIC) and
Coulomb torque (``--frictions``, tau_s = 1.5 tau_c): ``--seeds`` recordings of the paper's arm
at location 2 (force noise 0.05 N, 2^18-count encoders, voluntary force 0.3 N RMS below
2 Hz, perturbation peak 10 N, ``--seconds`` s), each estimated by ``aj.identify`` (the arm's
12 entries, the robot's friction known) and by the classical route of the same recording
(Welch + ``fit_impedance`` with the acquisition's model and spectral SEs). Per cell: the
share of 95% intervals holding the truth over the 12 entries, and the bias of the
estimates (the largest |mean error| over the spread of the estimates, over the entries).
Writes a strict JSON (``--out``, resumed when rerun with the same settings), prints a
Markdown table and draws ``--figure``.

    python sweeps/identify_study.py --seeds 25 --out identify_study.json --figure docs/figures/identification_study.png
"""

from __future__ import annotations

import pathlib
import sys
import types

from _cli import Z95, Parser, fail, resumable

ARM = ("arm.mass", "arm.damping", "arm.stiffness")
ACQUISITIONS = ("instant", "interval_mean")
CONTROLLERS = ("pd", "imbic")


def parse(argv):
    p = Parser(prog="identify_study", description=__doc__.split("\n\n")[0])
    p.add_argument("--seeds", type=int, default=25, help="recordings per cell (default 25)")
    p.add_argument("--seconds", type=float, default=10.0, help="record length [s] (default 10)")
    p.add_argument("--frictions", default="0,0.2,1,4", help="Coulomb torques [N m] (default 0,0.2,1,4)")
    p.add_argument("--draws", type=int, default=64, help="identify's noise draws (default 64)")
    p.add_argument("--out", default="identify_study.json", help="JSON file of the results (resumed if present)")
    p.add_argument("--figure", default=None, help="PNG of the bias and coverage against friction")
    a = p.parse_args(argv)
    try:
        a.frictions = [float(t) for t in a.frictions.split(",")]
    except ValueError:
        fail(f"--frictions must be numbers like 0,0.2,1; got {a.frictions!r}", p.prog)
    if a.seeds < 3 or a.seconds < 2 or a.draws < 8 or any(t < 0 for t in a.frictions):
        fail("need --seeds >= 3, --seconds >= 2, --draws >= 8 and frictions >= 0", p.prog)
    return a


def cell_summary(np, rows, true):
    """Coverage and bias over the 12 entries, for identify and the classical route."""
    out = {}
    for route, values, half in (("identify", "values", None), ("classical", "classical", "classical_half_width")):
        e = np.array([np.concatenate([np.ravel(r[values][n]) for n in ARM]) for r in rows])
        if half is None:
            w = Z95 * np.array([np.concatenate([np.ravel(r["se"][n]) for n in ARM]) for r in rows])
        else:
            w = np.array([np.concatenate([np.ravel(r[half][n]) for n in ARM]) for r in rows])
        spread = e.std(axis=0, ddof=1)
        out[route] = dict(
            coverage=float(np.mean(np.abs(e - true) <= w)),
            worst_entry_coverage=float(np.min(np.mean(np.abs(e - true) <= w, axis=0))),
            bias_over_spread=float(np.max(np.abs(e.mean(axis=0) - true) / spread)),
            spread=spread.tolist(),
        )
    out["classical_over_identify_spread"] = float(
        np.median(np.array(out["classical"]["spread"]) / np.array(out["identify"]["spread"]))
    )
    return out


def run(aj, np, jax, a):
    from bench_identify_coverage import make_truth, run_case

    from armimp_jax.study import atomic_write_json

    settings = {k: v for k, v in vars(a).items() if k not in ("out", "figure")}
    path = pathlib.Path(a.out)
    state = resumable(path, settings, "identify_study", cells={})
    f = aj.perturbation(jax.random.key(2024), int(round(a.seconds * 1000)), 10.0)
    for acquisition in ACQUISITIONS:
        opts = types.SimpleNamespace(acquisition=acquisition, voluntary=0.3, free=ARM, draws=a.draws)
        for controller in CONTROLLERS:
            for tau_c in a.frictions:
                name = f"{acquisition}/{controller}/{tau_c:g}"
                truth = make_truth(aj, controller, tau_c, opts)
                cell = run_case(aj, np, jax, state, "cells", name, truth, f, opts, seeds=a.seeds, path=path)
                # scored: recordings whose fit converged (the rest are counted in the summary)
                rows = [r for r in cell["seeds"] if not r["diverged"] and r["converged"] and "classical" in r]
                true = np.concatenate([np.ravel(getattr(truth.arm, n.split(".")[1])) for n in ARM])
                cell["summary"] = dict(
                    cell_summary(np, rows, true),
                    scored=len(rows),
                    not_converged=sum(not r["diverged"] and not r["converged"] for r in cell["seeds"]),
                    diverged=sum(bool(r["diverged"]) for r in cell["seeds"]),
                )
                atomic_write_json(path, state)
                s = cell["summary"]
                print(
                    f"{name}: coverage identify {s['identify']['coverage']:.2f}, classical "
                    f"{s['classical']['coverage']:.2f}; bias/spread identify {s['identify']['bias_over_spread']:.2f}, "
                    f"classical {s['classical']['bias_over_spread']:.2f}",
                    flush=True,
                )
    return state


def table(state, a) -> str:
    lines = [
        "| acquisition | controller | tau_c [N m] | coverage: identify | classical | worst entry: identify | "
        "classical | bias / spread: identify | classical | classical spread / identify's |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, cell in state["cells"].items():
        acq, controller, tau_c = name.split("/")
        s = cell["summary"]
        i, c = s["identify"], s["classical"]
        lines.append(
            f"| {acq} | {controller} | {tau_c} | {i['coverage']:.2f} | {c['coverage']:.2f} | "
            f"{i['worst_entry_coverage']:.2f} | {c['worst_entry_coverage']:.2f} | {i['bias_over_spread']:.2f} | "
            f"{c['bias_over_spread']:.2f} | {s['classical_over_identify_spread']:.2f} |"
        )
    return "\n".join(lines)


def figure(state, a, path):
    import numpy as np
    from matplotlib.figure import Figure

    from armimp_jax.study import save_figure

    fig = Figure(figsize=(12, 7), layout="constrained")
    axes = fig.subplots(2, 2, sharex=True)
    x = np.arange(len(a.frictions))
    for col, controller in enumerate(CONTROLLERS):
        for acq, marker in zip(ACQUISITIONS, ("o", "s")):
            for route, style in (("identify", "-"), ("classical", ":")):
                cells = [state["cells"][f"{acq}/{controller}/{t:g}"]["summary"][route] for t in a.frictions]
                label = f"{route}, {acq.replace('_', '-')}"
                axes[0, col].plot(x, [c["coverage"] for c in cells], style, marker=marker, label=label)
                axes[1, col].plot(x, [c["bias_over_spread"] for c in cells], style, marker=marker, label=label)
        axes[0, col].axhline(0.95, color="k", lw=0.8)
        axes[0, col].set_ylim(0.5, 1.02)
        axes[0, col].set_title(f"{controller.upper()}: share of 95% intervals holding the truth", fontsize=10)
        axes[1, col].set_ylim(bottom=0.0)
        axes[1, col].set_title(f"{controller.upper()}: largest |mean error| / spread over the 12 entries", fontsize=10)
        axes[1, col].set_xticks(x, [f"{t:g}" for t in a.frictions])
        axes[1, col].set_xlabel("Coulomb friction tau_c [N m] (tau_s = 1.5 tau_c)")
    axes[0, 1].legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
    return save_figure(fig, path)


def main(argv=None):
    a = parse(sys.argv[1:] if argv is None else argv)
    import jax

    jax.config.update("jax_enable_x64", True)
    from armimp_jax import runtime

    runtime.use_compilation_cache(runtime.compilation_cache_dir())  # a second run loads, not compiles
    import numpy as np

    import armimp_jax as aj

    state = run(aj, np, jax, a)
    print()
    print(table(state, a))
    if a.figure:
        print(f"figure: {figure(state, a, a.figure)}")


if __name__ == "__main__":
    main()
