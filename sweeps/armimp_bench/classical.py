"""``identify`` against the classical route over friction, controller and acquisition, with
the person's own force on (``sweeps/identify_study.py``; docs/identification.md, section 7):
per cell, recordings of the paper's arm at location 2 identified both ways, on the study
engine (``study.sweep.coverage.Recordings``); the coverage and bias of each route, a table and a
figure.
"""

from __future__ import annotations

import types

import jax
import numpy as np
from matplotlib.figure import Figure

import armimp_jax as aj
from armimp_jax.study.runs.results import atomic_write_json, stamped
from armimp_jax.study.sweep import coverage as cov
from armimp_jax.study.sweep.figures import save_figure

from .identification import make_truth

ARM = cov.ARM
Z95 = cov.Z95
ACQUISITIONS = ("instant", "interval_mean")
CONTROLLERS = ("pd", "imbic")


def cell_summary(rows, true):
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


def run(a, out, *, console=None) -> dict:
    """The study of options ``a`` (``identify_study.py``'s) in run folder ``out``: per cell
    ``acquisition/controller/tau_c`` its summary, also written to ``out/identify_study.json``."""
    settings = {k: v for k, v in vars(a).items() if k not in ("out", "figure", "seeds")}
    f = aj.perturbation(jax.random.key(2024), int(round(a.seconds * 1000)), 10.0)
    cells = {
        f"{acq}/{controller}/{tau_c:g}": (acq, controller, tau_c)
        for acq in ACQUISITIONS
        for controller in CONTROLLERS
        for tau_c in a.frictions
    }

    def make(name):
        acquisition, controller, tau_c = cells[name]
        opts = types.SimpleNamespace(acquisition=acquisition, voluntary=0.3, free=ARM, draws=a.draws, friction="lugre")
        return make_truth(controller, tau_c, opts), f

    def one(truth, f, name, seed):
        return cov.identify_row(truth, f, seed, free=ARM, draws=a.draws)

    def finish(run, rows):
        state = dict(cells={})
        for name, rs in rows.items():
            truth, _ = make(name)
            # scored: recordings whose fit converged (the rest are counted in the summary)
            scored = [r for r in rs if not r["diverged"] and r["converged"] and "classical" in r]
            true = np.concatenate([np.ravel(getattr(truth.arm, n.split(".")[1])) for n in ARM])
            summary = dict(
                cell_summary(scored, true),
                scored=len(scored),
                not_converged=sum(not r["diverged"] and not r["converged"] for r in rs),
                diverged=sum(bool(r["diverged"]) for r in rs),
            )
            state["cells"][name] = dict(seeds=rs, summary=summary)
        atomic_write_json(run.path / "identify_study.json", dict(settings=stamped(settings)) | state)
        return state

    spec = cov.Recordings("identify_study", settings, list(cells), range(a.seeds), make, one)
    return cov.run_recordings(spec, out, console=console, finish=finish).finished


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
