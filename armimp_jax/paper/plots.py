"""Figures of a reproduction run, drawn from saved results only (so ``--replot`` needs no simulation).

Counterparts of the paper's figures: true vs estimated ``Z_h`` per friction level (Figs. 2
and 7; magnitude, and phase error in place of the two phases), multiple and partial
coherences (Figs. 3 and 8), bar charts of ``phi_T`` and ``phi_ij`` (Figs. 4 and 9), plus the
acquisition ablation.

Conventions, so that a figure can be read at a glance: bars start from zero on linear
axes; with several seeds, curves are the mean over the seeds that did not diverge with a
band, and bars carry error bars, both the 95% t-interval of the mean; with one seed there
are neither. Bode figures draw the phase as the estimate's phase error, bin by bin within
+-180 deg (over seeds, around their circular mean), broken where it crosses +-180 deg.
Legends sit outside the axes, titles wrap to the figure's width. IMBIC's figures carry PD
as the reference; labels are words.
"""

from __future__ import annotations

import pathlib

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.patches import Patch  # noqa: E402

from ..presets._paper import arm  # noqa: E402
from ..study.sweep.figures import save_figure  # noqa: E402
from ..study.sweep.stats import mean_ci  # noqa: E402
from ._text import short  # noqa: E402

FRICTION_COLORS = {0: "tab:blue", 1: "tab:orange", 2: "tab:red"}
ELEMENTS = ((0, 0), (0, 1), (1, 0), (1, 1))
NAMES = {"pd": "PD", "imbic": "IMBIC"}
PD_STYLE = dict(hatch="//", edgecolor="0.25", alpha=0.55)  # PD drawn as the reference in IMBIC's figures


def _save(fig, path: pathlib.Path) -> pathlib.Path:
    fig.tight_layout()
    return save_figure(fig, path)


def condition_label(cond: dict) -> str:
    """``"PD, friction 2, location 1, perturbation 1"`` (plus the acquisition when not instant)."""
    acq = "" if cond.get("acquisition", "instant") == "instant" else ", interval-mean acquisition"
    return (
        f"{NAMES.get(cond['experiment'], cond['experiment'])}, friction {cond['friction']}, "
        f"location {cond['location']}, perturbation {cond['perturbation']}{acq}"
    )


def _spread_note(ns, what: str = "bands") -> str:
    """What the ``what`` (bands, error bars) of a figure are, from the seed counts ``ns`` drawn."""
    ns = sorted({int(n) for n in ns if n})
    if not ns:
        return "no trials"
    if ns[-1] == 1:
        return f"1 seed: no {what}"
    seeds = f"{ns[0]}" if len(ns) == 1 else f"{ns[0]}-{ns[-1]}"
    return f"mean of {seeds} seeds; {what}: 95% CI of the mean"


def _interval(half, n):
    """The CI half-width to draw: none with fewer than two seeds."""
    if half is None or n is None or n < 2:
        return None
    return np.nan_to_num(np.asarray(half, dtype=float), nan=0.0)


# --- per-trial arrays ----------------------------------------------------------------------


def _seed_arrays(results, arrays, *, experiment, location, perturbation, acquisition="instant"):
    """``{friction: [arrays of each seed that did not diverge, by seed]}`` of one cell."""
    out: dict[int, list] = {}
    for t in sorted(results["trials"], key=lambda t: t["seed"]):
        c = t["condition"]
        if t["diverged"] or t["id"] not in arrays:
            continue
        if (c["experiment"], c["location"], c["perturbation"], c["acquisition"]) == (
            experiment,
            location,
            perturbation,
            acquisition,
        ):
            out.setdefault(c["friction"], []).append(arrays[t["id"]])
    return dict(sorted(out.items()))


def wrap_deg(d):
    """Angles [deg] wrapped into ``[-180, 180)``."""
    return (np.asarray(d, dtype=float) + 180.0) % 360.0 - 180.0


def phase_error_deg(z, truth):
    """Phase errors [deg] of the estimates ``z`` ``(S, F)`` against the complex ``truth``
    ``(F,)``, bin by bin: ``c + wrap(e_s - c)`` with ``e_s = angle(z_s / truth)`` and ``c``
    their circular mean. One estimate gets exactly its phase error, within 180 deg of 0 (no
    unwrapping, so whole turns picked up from noise never show as a 360 deg gap); several
    stay together around their circular mean, which the branch edge does not split."""
    err = np.degrees(np.angle(np.atleast_2d(z) / truth))
    c = np.degrees(np.angle(np.exp(1j * np.radians(err)).sum(axis=0)))
    return c + wrap_deg(err - c)


def _break_jumps(f, samples, limit: float = 180.0):
    """``(f, samples)`` with a NaN bin inserted wherever the mean of ``samples`` ``(S, F)``
    jumps by more than ``limit`` between neighbouring bins: a phase error crossing +-180 deg
    is drawn broken, not as a vertical stroke across the panel."""
    cut = np.flatnonzero(np.abs(np.diff(samples.mean(axis=0))) > limit)
    if cut.size == 0:
        return f, samples
    return np.insert(f, cut + 1, (f[cut] + f[cut + 1]) / 2), np.insert(samples, cut + 1, np.nan, axis=1)


def _legend_outside(ax, handles=None, labels=None, **kw):
    """A legend to the right of ``ax``, outside every plotting area (``tight_layout`` makes room)."""
    if handles is None:
        handles, labels = ax.get_legend_handles_labels()
    if labels is None:
        labels = [h.get_label() for h in handles]
    return ax.legend(handles, labels, loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0.0, fontsize=8, **kw)


def _line(ax, x, samples, *, color, label, ls="-", lw=1.4, log=False, clip=(-np.inf, np.inf)):
    """Mean of ``samples`` ``(S, F)`` with its 95% CI band (clipped to ``clip``) when ``S > 1``;
    returns ``(S, mean)``."""
    samples = np.asarray(samples, dtype=float)
    mean, _, half = mean_ci(samples)
    if log:
        ax.loglog(x, mean, color=color, ls=ls, lw=lw, label=label)
    else:
        ax.plot(x, mean, color=color, ls=ls, lw=lw, label=label)
    if half is not None:
        ax.fill_between(x, np.clip(mean - half, *clip), np.clip(mean + half, *clip), color=color, alpha=0.2, lw=0)
    return samples.shape[0], mean


# --- Bode plots (Figs. 2 and 7) ------------------------------------------------------------


def bode_figure(results, arrays, path: pathlib.Path, *, experiment: str, location: int = 1, perturbation: int = 1):
    """True vs estimated magnitude of the four elements of ``Z_h`` (top) and the estimates'
    phase error (bottom, ``phase_error_deg``: 0 is the true phase), per friction level;
    IMBIC's figure adds PD at the highest friction level as the reference."""
    picked = _seed_arrays(results, arrays, experiment=experiment, location=location, perturbation=perturbation)
    if not picked:
        return None
    refs = {}
    if experiment != "pd":
        pd = _seed_arrays(results, arrays, experiment="pd", location=1, perturbation=1)
        pd = {fr: a for fr, a in pd.items() if fr > 0}
        if pd:
            refs = dict([max(pd.items())])
    fig, axes = plt.subplots(2, 4, figsize=(17, 7.2), sharex=True)
    f = picked[next(iter(picked))][0]["f"]
    zt = np.asarray(arm(location).impedance(f))
    ns = []
    for col, (i, j) in enumerate(ELEMENTS):
        axes[0, col].loglog(f, np.abs(zt[:, i, j]), "k--", lw=2, label=f"true $Z_h$, location {location}")
        axes[1, col].semilogx(f, np.zeros_like(f), "k--", lw=2)
        curves = [(fr, runs, "-", f"{NAMES[experiment]}, friction {fr}") for fr, runs in picked.items()]
        curves += [(fr, runs, ":", f"PD, friction {fr}, location 1 (reference)") for fr, runs in refs.items()]
        for fr, runs, ls, label in curves:
            ref_f = runs[0]["f"]
            if ref_f.shape != f.shape or not np.allclose(ref_f, f):
                continue
            z = np.stack([a["Z"][:, i, j] for a in runs])
            f_ph, err = _break_jumps(f, phase_error_deg(z, zt[:, i, j]))
            color = FRICTION_COLORS.get(fr, "0.3")
            ns.append(_line(axes[0, col], f, np.abs(z), color=color, label=label, ls=ls, log=True)[0])
            _line(axes[1, col], f_ph, err, color=color, label=None, ls=ls)
        axes[1, col].set_ylim(-180, 180)
        axes[1, col].set_yticks(np.arange(-180, 181, 90))
        axes[0, col].set_title(f"$Z_{{{i + 1}{j + 1}}}$")
        axes[1, col].set_xlabel("frequency [Hz]")
        axes[0, col].grid(alpha=0.3)
        axes[1, col].grid(alpha=0.3)
    axes[0, 0].set_ylabel("magnitude [N/m]")
    axes[1, 0].set_ylabel("phase error [deg]\n(estimate - truth; 0: exact)")
    _legend_outside(axes[0, -1], *axes[0, 0].get_legend_handles_labels())
    fig.suptitle(
        f"{NAMES[experiment]}: true vs estimated arm impedance, location {location}, perturbation {perturbation}: "
        f"magnitude (top) and phase error (bottom)\n({_spread_note(ns)})"
    )
    return _save(fig, path)


# --- coherences (Figs. 3 and 8) ------------------------------------------------------------


def _min_coherence(c) -> float:
    values = [c.get("coh_multiple_x_min_low"), c.get("coh_multiple_x_min_high")]
    values = [v for v in values if v is not None and np.isfinite(v)]
    return min(values) if values else np.inf


def worst_cell(results, experiment: str) -> tuple[int, int, float, int | None]:
    """``(location, perturbation, value, friction)`` of the cell of ``experiment`` (instant
    acquisition) whose minimum multiple coherence of ``x`` (mean over seeds) is lowest;
    ``(1, 1, nan, None)`` when the results hold none."""
    best = (1, 1, np.nan, None)
    lowest = np.inf
    for c in results["conditions"]:
        cond = c["condition"]
        if cond["experiment"] != experiment or cond["acquisition"] != "instant":
            continue
        v = _min_coherence(c)
        if v < lowest:
            lowest, best = v, (cond["location"], cond["perturbation"], v, cond["friction"])
    return best


def coherence_figure(results, arrays, path: pathlib.Path, *, experiment: str, location=None, perturbation=None):
    """Multiple and partial coherences of the position outputs, per friction level, at the
    cell with the lowest minimum multiple coherence (``worst_cell``) unless ``location`` /
    ``perturbation`` are given. IMBIC's figure adds PD (location 1, perturbation 1, highest
    friction level) as the reference."""
    w_loc, w_pert, w_value, w_fr = worst_cell(results, experiment)
    chosen = location is None and perturbation is None
    location = w_loc if location is None else location
    perturbation = w_pert if perturbation is None else perturbation
    picked = _seed_arrays(results, arrays, experiment=experiment, location=location, perturbation=perturbation)
    if not picked:
        return None
    curves = [(fr, runs, "-", f"{NAMES[experiment]}, friction {fr}") for fr, runs in picked.items()]
    if experiment != "pd":
        pd = {fr: a for fr, a in _seed_arrays(results, arrays, experiment="pd", location=1, perturbation=1).items()}
        pd = {fr: a for fr, a in pd.items() if fr > 0}
        if pd:
            fr, runs = max(pd.items())
            curves.append((fr, runs, ":", f"PD, friction {fr}, location 1 (reference)"))
    fig, axes = plt.subplots(2, 3, figsize=(15, 7.4), sharex=True, sharey=True)
    ns = []
    for fr, runs, ls, label in curves:
        f = runs[0]["f"]
        color = FRICTION_COLORS.get(fr, "0.3")
        for out in range(2):
            mult = np.stack([a["coh_multiple_x"][:, out] for a in runs])
            ns.append(
                _line(axes[out, 0], f, mult, color=color, ls=ls, label=label if out == 0 else None, clip=(0, 1))[0]
            )
            if ls != "-":
                continue  # the reference only in the multiple coherence, to keep the panels readable
            for inp in range(2):
                part = np.stack([a["coh_partial_x"][:, out, inp] for a in runs])
                _line(axes[out, 1 + inp], f, part, color=color, ls=ls, label=None, clip=(0, 1))
    axes[0, 0].set_title("multiple coherence")
    for inp in range(2):
        axes[0, 1 + inp].set_title(f"partial coherence, input $F_{{\\Delta,{inp + 1}}}$")
    for out in range(2):
        axes[out, 0].set_ylabel(f"coherence, output $x_{out + 1}$")
    for ax in axes.flat:
        ax.set_ylim(0, 1.05)
        ax.axhline(0.9, color="0.6", lw=0.8, ls=":")
        ax.grid(alpha=0.3)
    for ax in axes[1]:
        ax.set_xlabel("frequency [Hz]")
    _legend_outside(axes[0, -1], *axes[0, 0].get_legend_handles_labels())
    where = f"location {location}, perturbation {perturbation}"
    if chosen and np.isfinite(w_value):
        lowest = short(w_value, ".2f")  # a coherence of 0.996 is not "1.00"
        where += f"\nthe run's lowest minimum multiple coherence (friction {w_fr}: {lowest}, mean of the seeds' minima)"
    fig.suptitle(f"{NAMES[experiment]}: coherence of the position estimate at {where}\n({_spread_note(ns)})")
    return _save(fig, path)


# --- phi bars (Figs. 4 and 9) --------------------------------------------------------------


def _cond_table(results, acquisition="instant"):
    """``{(experiment, location, friction, perturbation): condition stats}``."""
    return {
        (
            c["condition"]["experiment"],
            c["condition"]["location"],
            c["condition"]["friction"],
            c["condition"]["perturbation"],
        ): c
        for c in results["conditions"]
        if c["condition"]["acquisition"] == acquisition
    }


def _bars(ax, pos, heights, errs, *, width, horizontal=False, **style):
    """Bars with error bars where ``errs`` holds a half-width (``None``: no error bar)."""
    err = None if all(e is None for e in errs) else np.array([np.nan if e is None else float(e) for e in errs])
    if horizontal:
        return ax.barh(pos, heights, width, xerr=err, capsize=2, **style)
    return ax.bar(pos, heights, width, yerr=err, capsize=2, **style)


def _pick_metric(value, sel):
    if value is None:
        return None
    return value if sel is None else value[sel[0]][sel[1]]


def _phi(c, sel):
    """Mean, 95% CI half-width (None with one seed) and ``n`` of phi_T (``sel`` None) or phi_ij."""
    name = "phi_T" if sel is None else "phi_ij"
    mean, half = _pick_metric(c.get(name), sel), _pick_metric(c.get(name + "_ci"), sel)
    return mean, half, c.get("n", 1)


def _seed_metric(results, acquisition="instant"):
    """``{(experiment, location, friction, perturbation): {seed: metrics}}`` of the trials
    that did not diverge."""
    out: dict = {}
    for t in results["trials"]:
        c = t["condition"]
        if t["diverged"] or c["acquisition"] != acquisition:
            continue
        out.setdefault((c["experiment"], c["location"], c["friction"], c["perturbation"]), {})[t["seed"]] = t["metrics"]
    return out


def _ratio(per_seed, key, ref_key, sel):
    """Mean, CI half-width and ``n`` of phi(``key``) / phi(``ref_key``) over the seeds both
    hold (paired: every condition sees the same perturbation for the same seed)."""
    name = "phi_T" if sel is None else "phi_ij"
    a, b = per_seed.get(key, {}), per_seed.get(ref_key, {})
    ratios = []
    for s in sorted(a.keys() & b.keys()):
        num, den = _pick_metric(a[s].get(name), sel), _pick_metric(b[s].get(name), sel)
        if num is not None and den is not None and np.isfinite(num) and np.isfinite(den) and den > 0:
            ratios.append(num / den)
    if not ratios:
        return None, None, 0
    mean, _, half = mean_ci(ratios)
    return float(mean), None if half is None else float(half), len(ratios)


def phi_bars(results, path: pathlib.Path, *, experiment: str):
    """phi_T and the four phi_ij as bars from zero (top row, [N/m]) and as ratios to the
    frictionless case of the same cell, seed by seed (bottom row), coloured by friction
    level: PD over perturbation levels (location 1), IMBIC over locations (perturbation 1)
    next to PD at location 1, perturbation 1 (hatched, the reference)."""
    table = _cond_table(results)
    frictions = sorted({k[2] for k in table})
    if experiment == "pd":
        perts = sorted({k[3] for k in table if k[0] == "pd"})
        groups = [(f"perturbation {p}", ("pd", 1, p)) for p in perts]
    else:
        locs = sorted({k[1] for k in table if k[0] == experiment})
        groups = [(f"location {loc}", (experiment, loc, 1)) for loc in locs]
        if any(k[0] == "pd" and k[1] == 1 and k[3] == 1 for k in table):
            groups = [("PD at\nlocation 1\n(reference)", ("pd", 1, 1))] + groups
    cells = [(e, loc, fr, p) for _, (e, loc, p) in groups for fr in frictions]
    if not any(table.get(k, {}).get("phi_T") is not None for k in cells if k[0] == experiment):
        return None  # no condition of the experiment has numbers (all diverged or absent)
    per_seed = _seed_metric(results)
    panels = [("$\\phi_T$", None)] + [(f"$\\phi_{{{i + 1}{j + 1}}}$", (i, j)) for i, j in ELEMENTS]
    fig, axes = plt.subplots(2, len(panels), figsize=(21, 8))
    width = 0.8 / len(frictions)
    x = np.arange(len(groups))
    ns = []
    for col, (title, sel) in enumerate(panels):
        top, bottom = axes[0, col], axes[1, col]
        # one bar() call per (row, friction, reference or not): many single bars draw slowly
        bars: dict[tuple, list] = {}
        for m_i, fr in enumerate(frictions):
            offset = (m_i - (len(frictions) - 1) / 2) * width
            for g_i, (_, (e, loc, p)) in enumerate(groups):
                ref = experiment != "pd" and e == "pd"
                c = table.get((e, loc, fr, p))
                mean, half, n = (None, None, 0) if c is None else _phi(c, sel)
                if mean is None or not np.isfinite(mean):
                    if c is not None:  # every trial diverged: say so where the bar would be
                        top.text(g_i + offset, 0, "all diverged", ha="center", va="bottom", fontsize=6, rotation=90)
                    continue
                ns.append(n)
                bars.setdefault((0, fr, ref), []).append((g_i + offset, mean, _interval(half, n)))
                if fr != 0 and 0 in frictions:
                    r, r_half, r_n = _ratio(per_seed, (e, loc, fr, p), (e, loc, 0, p), sel)
                    if r is not None:
                        bars.setdefault((1, fr, ref), []).append((g_i + offset, r, _interval(r_half, r_n)))
        for (row, fr, ref), items in bars.items():
            pos, heights, errs = zip(*items)
            _bars(
                axes[row, col],
                pos,
                heights,
                errs,
                width=width,
                color=FRICTION_COLORS.get(fr, "0.5"),
                label=f"friction {fr}" if row == 0 and not ref else None,
                **(PD_STYLE if ref else {}),
            )
        for ax in (top, bottom):
            ax.set_xticks(x, [g[0] for g in groups], fontsize=8)
            ax.set_xlim(-0.6, len(groups) - 0.4)
            ax.set_ylim(bottom=0)
            ax.grid(alpha=0.3, axis="y")
            if experiment != "pd" and groups[0][1][0] == "pd":
                ax.axvline(0.5, color="0.4", lw=0.8)
        bottom.axhline(1.0, color="k", lw=0.8, ls="--")
        top.set_title(title)
    axes[0, 0].set_ylabel("estimation error [N/m]")
    axes[1, 0].set_ylabel("ratio to friction 0\n(same cell, seed by seed)")
    handles, _ = axes[0, 0].get_legend_handles_labels()
    if experiment != "pd" and groups[0][1][0] == "pd":
        handles.append(Patch(facecolor="white", label="PD, location 1 (reference)", **PD_STYLE))
    _legend_outside(axes[0, -1], handles)
    where = "PD, location 1" if experiment == "pd" else "IMBIC, perturbation 1, next to PD (hatched, location 1)"
    fig.suptitle(f"{where}: error of the impedance estimate, lower is better\n({_spread_note(ns, 'error bars')})")
    return _save(fig, path)


# --- acquisition ablation ------------------------------------------------------------------


def ablation_figure(results, path: pathlib.Path):
    """phi_T with instant sampling vs interval-mean acquisition, condition by condition
    (horizontal bars from zero, one row per condition)."""
    rows = []
    for c in results["conditions"]:
        cond = c["condition"]
        if cond["acquisition"] != "instant":
            continue
        twin = next(
            (d for d in results["conditions"] if d["condition"] == dict(cond, acquisition="interval_mean")), None
        )
        if twin is not None and c["phi_T"] is not None and twin["phi_T"] is not None:
            rows.append((condition_label(cond), c, twin))
    if not rows:
        return None
    rows.sort(key=lambda r: (r[1]["condition"]["experiment"] != "pd", r[0]))
    fig, ax = plt.subplots(figsize=(12, 1.5 + 0.32 * len(rows)))
    y = np.arange(len(rows))[::-1]
    ns = []
    for offset, idx, label, color in (
        (0.2, 1, "instant samples (the reproduction)", "tab:gray"),
        (-0.2, 2, "interval mean (anti-aliased)", "tab:green"),
    ):
        vals = [r[idx]["phi_T"] for r in rows]
        n = [r[idx].get("n", 1) for r in rows]
        ns += n
        errs = [_interval(r[idx].get("phi_T_ci"), k) for r, k in zip(rows, n)]
        _bars(ax, y + offset, vals, errs, width=0.4, horizontal=True, label=label, color=color)
    ax.set_yticks(y, [r[0] for r in rows], fontsize=8)
    ax.set_xlim(left=0)
    ax.set_xlabel("$\\phi_T$ [N/m] (lower is better)")
    ax.grid(alpha=0.3, axis="x")
    _legend_outside(ax)
    ax.set_title(
        f"Ablation: how much of the error is the sampling of the force signal\n({_spread_note(ns, 'error bars')})"
    )
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
