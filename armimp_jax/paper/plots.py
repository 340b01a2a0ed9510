"""Figures of a reproduction run, drawn from saved results only (so ``--replot`` needs no simulation).

Counterparts of the paper's figures: Bode plots of true vs estimated ``Z_h`` per friction
level (Figs. 2 and 7), multiple and partial coherences (Figs. 3 and 8), bar charts of
``phi_T`` and ``phi_ij`` (Figs. 4 and 9), plus the acquisition ablation.
"""

from __future__ import annotations

import pathlib

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ._presets import arm  # noqa: E402

FRICTION_COLORS = {0: "tab:blue", 1: "tab:orange", 2: "tab:red"}


def _save(fig, path: pathlib.Path) -> pathlib.Path:
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


ELEMENTS = ((0, 0), (0, 1), (1, 0), (1, 1))


def _pick(results, arrays, *, experiment, location, perturbation, acquisition="instant"):
    """``{friction: arrays}`` of the chosen trials: the lowest seed that did not diverge."""
    out = {}
    for t in sorted(results["trials"], key=lambda t: t["seed"]):
        c = t["condition"]
        if t["diverged"] or (c["experiment"], c["location"], c["perturbation"], c["acquisition"]) != (
            experiment,
            location,
            perturbation,
            acquisition,
        ):
            continue
        out.setdefault(c["friction"], arrays[t["id"]])
    return dict(sorted(out.items()))


def bode_figure(results, arrays, path: pathlib.Path, *, experiment: str, location: int = 1, perturbation: int = 1):
    """True vs estimated magnitude and phase of the four elements of ``Z_h``."""
    picked = _pick(results, arrays, experiment=experiment, location=location, perturbation=perturbation)
    if not picked:
        return None
    fig, axes = plt.subplots(2, 4, figsize=(15, 6.5), sharex=True)
    f = next(iter(picked.values()))["f"]
    zt = np.asarray(arm(location).impedance(f))
    for col, (i, j) in enumerate(ELEMENTS):
        axes[0, col].loglog(f, np.abs(zt[:, i, j]), "k--", lw=2, label="true $Z_h$")
        axes[1, col].semilogx(f, np.degrees(np.angle(zt[:, i, j])), "k--", lw=2)
        for fr, a in picked.items():
            z = a["Z"][:, i, j]
            axes[0, col].loglog(f, np.abs(z), color=FRICTION_COLORS[fr], label=f"friction {fr}")
            axes[1, col].semilogx(f, np.degrees(np.angle(z)), color=FRICTION_COLORS[fr])
        axes[0, col].set_title(f"$Z_{{{i + 1}{j + 1}}}$")
        axes[1, col].set_xlabel("frequency [Hz]")
        axes[1, col].set_ylim(-200, 200)
    axes[0, 0].set_ylabel("magnitude [N/m]")
    axes[1, 0].set_ylabel("phase [deg]")
    axes[0, 0].legend(fontsize=8)
    title = "PD" if experiment == "pd" else "IMBIC"
    fig.suptitle(f"{title}: true vs estimated arm impedance, location {location}, perturbation level {perturbation}")
    return _save(fig, path)


def coherence_figure(results, arrays, path: pathlib.Path, *, experiment: str, location: int = 1, perturbation: int = 1):
    """Multiple and partial coherences of the position outputs, per friction level."""
    picked = _pick(results, arrays, experiment=experiment, location=location, perturbation=perturbation)
    if not picked:
        return None
    fig, axes = plt.subplots(2, 3, figsize=(13, 6.5), sharex=True, sharey=True)
    for fr, a in picked.items():
        f = a["f"]
        for out in range(2):
            axes[out, 0].plot(f, a["coh_multiple_x"][:, out], color=FRICTION_COLORS[fr], label=f"friction {fr}")
            for inp in range(2):
                axes[out, 1 + inp].plot(f, a["coh_partial_x"][:, out, inp], color=FRICTION_COLORS[fr])
    for out in range(2):
        axes[out, 0].set_ylabel(f"output $x_{out + 1}$")
        axes[out, 0].set_title("multiple" if out == 0 else "")
        for inp in range(2):
            if out == 0:
                axes[out, 1 + inp].set_title(f"partial, input $F_{{\\Delta,{inp + 1}}}$")
    for ax in axes.flat:
        ax.set_ylim(0, 1.05)
        ax.axhline(0.9, color="0.6", lw=0.8, ls=":")
        ax.grid(alpha=0.3)
    for ax in axes[1]:
        ax.set_xlabel("frequency [Hz]")
    axes[0, 0].legend(fontsize=8)
    title = "PD" if experiment == "pd" else "IMBIC"
    fig.suptitle(f"{title}: coherence of the position estimate, location {location}")
    return _save(fig, path)


def _cond_table(results, experiment, acquisition="instant"):
    return {
        (c["condition"]["location"], c["condition"]["friction"], c["condition"]["perturbation"]): c
        for c in results["conditions"]
        if c["condition"]["experiment"] == experiment and c["condition"]["acquisition"] == acquisition
    }


def _phi_value(c, sel):
    """Mean and 95% CI half-width of phi_T (``sel`` None) or of element ``sel`` of phi_ij."""
    if sel is None:
        return c["phi_T"], c.get("phi_T_ci")
    mean, half = c["phi_ij"], c.get("phi_ij_ci")
    return (
        None if mean is None else mean[sel[0]][sel[1]],
        None if half is None else half[sel[0]][sel[1]],
    )


def phi_bars(results, path: pathlib.Path, *, experiment: str):
    """phi_T and the four phi_ij as grouped bars: PD over friction x perturbation level,
    IMBIC over location x friction. Bars: means over the seeds that did not diverge; error
    bars: the 95% t-interval of the mean (none with one seed)."""
    # conditions whose every trial diverged have no numbers (and cannot go on a log axis)
    table = {k: c for k, c in _cond_table(results, experiment).items() if c["phi_T"] is not None}
    if not table:
        return None
    if experiment == "pd":
        groups, members = [0, 1, 2], [1, 2, 3]
        key = lambda g, m: (1, g, m)  # noqa: E731
        glabel, mlabel = "friction level", "perturbation level"
    else:
        groups, members = [1, 2, 3, 4], [0, 1, 2]
        key = lambda g, m: (g, m, 1)  # noqa: E731
        glabel, mlabel = "arm location", "friction level"
    fig, axes = plt.subplots(1, 5, figsize=(18, 4))
    width = 0.8 / len(members)
    for a_i, (name, sel) in enumerate([("phi_T", None)] + [(f"phi_{i + 1}{j + 1}", (i, j)) for i, j in ELEMENTS]):
        ax = axes[a_i]
        for m_i, m in enumerate(members):
            vals, errs = [], []
            for g in groups:
                c = table.get(key(g, m))
                value, half = (None, None) if c is None else _phi_value(c, sel)
                vals.append(np.nan if value is None else value)
                errs.append(0.0 if half is None else half)
            ax.bar(
                np.arange(len(groups)) + (m_i - (len(members) - 1) / 2) * width,
                vals,
                width,
                yerr=errs,
                label=f"{mlabel} {m}",
                capsize=2,
            )
        ax.set_xticks(range(len(groups)), [str(g) for g in groups])
        ax.set_xlabel(glabel)
        ax.set_yscale("log")
        ax.set_title(name.replace("phi_", "$\\phi_{") + "}$" if name != "phi_T" else "$\\phi_T$")
    axes[0].set_ylabel("[N/m]")
    axes[0].legend(fontsize=8)
    fig.suptitle(
        ("PD, location 1" if experiment == "pd" else "IMBIC, perturbation level 1")
        + ": accuracy of the impedance estimate (lower is better)"
    )
    return _save(fig, path)


def ablation_figure(results, path: pathlib.Path):
    """phi_T with instant sampling vs interval-mean acquisition, condition by condition."""
    rows = []
    for c in results["conditions"]:
        cond = c["condition"]
        if cond["acquisition"] != "instant":
            continue
        twin = next(
            (d for d in results["conditions"] if d["condition"] == dict(cond, acquisition="interval_mean")), None
        )
        if twin is not None:
            label = f"{cond['experiment'].upper()} L{cond['location']} F{cond['friction']} P{cond['perturbation']}"
            if c["phi_T"] is not None and twin["phi_T"] is not None:
                rows.append((label, c["phi_T"], twin["phi_T"]))
    if not rows:
        return None
    fig, ax = plt.subplots(figsize=(max(8, 0.45 * len(rows)), 4.5))
    x = np.arange(len(rows))
    ax.bar(x - 0.2, [r[1] for r in rows], 0.4, label="instant (paper)")
    ax.bar(x + 0.2, [r[2] for r in rows], 0.4, label="interval mean (anti-aliased)")
    ax.set_xticks(x, [r[0] for r in rows], rotation=70, fontsize=8)
    ax.set_yscale("log")
    ax.set_ylabel("$\\phi_T$ [N/m]")
    ax.legend()
    ax.set_title("Ablation: how much of the error is the sampling of the force signal")
    return _save(fig, path)


def all_figures(results, arrays, out: pathlib.Path) -> list[pathlib.Path]:
    """Every figure of a run into ``out``; returns the paths written."""
    out.mkdir(parents=True, exist_ok=True)
    made = [
        bode_figure(results, arrays, out / "fig2_pd_bode.png", experiment="pd"),
        coherence_figure(results, arrays, out / "fig3_pd_coherence.png", experiment="pd"),
        phi_bars(results, out / "fig4_pd_phi.png", experiment="pd"),
        bode_figure(results, arrays, out / "fig7_imbic_bode.png", experiment="imbic"),
        coherence_figure(results, arrays, out / "fig8_imbic_coherence.png", experiment="imbic"),
        phi_bars(results, out / "fig9_imbic_phi.png", experiment="imbic"),
        ablation_figure(results, out / "ablation_acquisition.png"),
    ]
    return [p for p in made if p is not None]


def loss_curve(history: list[dict], path: pathlib.Path):
    """Training loss per accepted step (and held-out phi_T where evaluated); rejected steps marked."""
    steps = [h for h in history if "loss" in h]
    fig, ax = plt.subplots(figsize=(7, 4))
    ax.plot([h["iteration"] for h in steps], [h["loss"] for h in steps], "o-", label="training loss (mean phi_T)")
    rejected = [h["iteration"] for h in history if str(h.get("event", "")).startswith("rejected")]
    if rejected:
        ax.plot(rejected, [steps[0]["loss"]] * len(rejected), "rx", label="rejected step (diverged)")
    evals = [h for h in steps if "eval" in h]
    if evals:
        ax.plot(
            [h["iteration"] for h in evals],
            [h["eval"]["mean_phi_T"] for h in evals],
            "s--",
            label="held-out phi_T (paper settings)",
        )
    ax.set_xlabel("iteration")
    ax.set_ylabel("[N/m]")
    ax.legend()
    ax.grid(alpha=0.3)
    ax.set_title("Tuning Mhat by gradient descent")
    return _save(fig, path)
