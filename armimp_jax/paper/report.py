"""The Markdown report of a reproduction run, written from ``results.json`` alone.

Numbers are means over the seeds whose trial did not diverge; ``±`` is the half-width of
the 95% t-interval of the mean (none with one seed); ``n`` counts the trials averaged and
``diverged`` those left out. Missing values (a condition whose every trial diverged) show
as ``—``.
"""

from __future__ import annotations

import pathlib

from ..results import atomic_write_text
from .claims import CI_LEVEL, LOW_BAND_HZ

DASH = "—"


def _num(x, fmt: str = ".0f") -> str:
    return DASH if x is None else format(x, fmt)


def _pm(mean, half, fmt: str = ".0f") -> str:
    if mean is None:
        return DASH
    return format(mean, fmt) if half is None else f"{format(mean, fmt)} ± {format(half, fmt)}"


def _times(k, x):
    return None if x is None else k * x


def _conds(results, experiment, acquisition="instant"):
    return [
        c
        for c in results["conditions"]
        if c["condition"]["experiment"] == experiment and c["condition"]["acquisition"] == acquisition
    ]


def _phi_table(results, experiment, acquisition="instant") -> list[str]:
    rows = _conds(results, experiment, acquisition)
    if not rows:
        return ["(no trials)"]
    head = [
        "| location | friction | perturbation | n | phi_T [N/m] | phi_11 | phi_12 | phi_21 | phi_22 | "
        "rel. error | phase err [deg] | diverged |",
        "|" + "---|" * 12,
    ]
    lines = []
    for c in rows:
        k = c["condition"]
        pij = c["phi_ij"] if c["phi_ij"] is not None else [[None, None], [None, None]]
        rel = (
            DASH
            if c["rel_error"] is None
            else _pm(100 * c["rel_error"], _times(100, c.get("rel_error_ci")), ".1f") + "%"
        )
        phase = _pm(c["phase_error_deg"], c.get("phase_error_deg_ci"), ".1f")
        lines.append(
            f"| {k['location']} | {k['friction']} | {k['perturbation']} | {c['n']} | "
            f"{_pm(c['phi_T'], c.get('phi_T_ci'))} | {_num(pij[0][0])} | {_num(pij[0][1])} | {_num(pij[1][0])} | "
            f"{_num(pij[1][1])} | {rel} | {phase} | {c['diverged']} |"
        )
    return head + lines


def _coherence_table(results, experiment) -> list[str]:
    rows = _conds(results, experiment)
    if not rows:
        return ["(no trials)"]
    b = f"{LOW_BAND_HZ:g} Hz"
    head = [
        f"| location | friction | perturbation | mult. x, f<{b} | mult. x, f>={b} | partial x, f<{b} | "
        f"partial x, f>={b} | mult. F_h, f<{b} | mult. F_h, f>={b} |",
        "|" + "---|" * 9,
    ]
    names = [
        "coh_multiple_x_min_low",
        "coh_multiple_x_min_high",
        "coh_partial_x_min_low",
        "coh_partial_x_min_high",
        "coh_multiple_fh_min_low",
        "coh_multiple_fh_min_high",
    ]
    lines = [
        f"| {c['condition']['location']} | {c['condition']['friction']} | {c['condition']['perturbation']} | "
        + " | ".join(_pm(c[n], c.get(n + "_ci"), ".3f") for n in names)
        + " |"
        for c in rows
    ]
    return head + lines


def _ablation_table(results) -> list[str]:
    pairs = []
    for c in results["conditions"]:
        k = c["condition"]
        if k["acquisition"] != "instant":
            continue
        twin = next((d for d in results["conditions"] if d["condition"] == dict(k, acquisition="interval_mean")), None)
        if twin and c["phi_T"] is not None and twin["phi_T"] is not None:
            pairs.append((k, c["phi_T"], twin["phi_T"]))
    if not pairs:
        return ["(the ablation was not run, or its trials diverged)"]
    lines = [
        "| experiment | location | friction | perturbation | phi_T instant | phi_T interval mean | ratio |",
        "|" + "---|" * 7,
    ]
    lines += [
        f"| {k['experiment']} | {k['location']} | {k['friction']} | {k['perturbation']} | {a:.0f} | {b:.0f} | "
        f"{b / a:.2f} |"
        for k, a, b in pairs
    ]

    # how much of the friction effect survives anti-aliased acquisition
    def effect(acq):
        sel = {
            d["condition"]["friction"]: d["phi_T"]
            for d in results["conditions"]
            if d["condition"]["experiment"] == "pd"
            and d["condition"]["acquisition"] == acq
            and d["condition"]["perturbation"] == 1
            and d["phi_T"] is not None
        }
        if 0 not in sel or 2 not in sel:
            return None
        return sel[2] / sel[0], sel[2] - sel[0]

    ins, mean = effect("instant"), effect("interval_mean")
    if ins and mean:
        (ri, di), (rm, dm) = ins, mean
        lines += [
            "",
            f"PD, location 1, perturbation 1: friction 2 raises phi_T {ri:.1f}x (by {di:.0f} N/m) with "
            f"instant sampling and {rm:.1f}x (by {dm:.0f} N/m) with interval means: "
            f"{100 * dm / di:.1f}% of the friction-caused increase survives anti-aliased acquisition.",
        ]
    return lines


def _interval(p) -> str:
    return DASH if p["ci"] is None else f"[{p['ci'][0]:.3g}, {p['ci'][1]:.3g}]"


def _claims_detail(results) -> list[str]:
    lines = [
        "| claim | quantity | on the means | threshold | per seed | 95% CI over seeds | the CI |",
        "|---|---|---|---|---|---|---|",
    ]
    for c in results["claims"]:
        for p in c["parts"]:
            seeds = ", ".join(f"{v:.3g}" for v in p["seed_values"]) or DASH
            lines.append(
                f"| ({c['key']}) | {p['label']} | {_num(p['value'], '.3g')} | {p['op']} {p['threshold']:.3g} | "
                f"{seeds} | {_interval(p)} | {p['ci_says'] or DASH} |"
            )
    return lines


def write_report(results: dict, out: pathlib.Path, figures: list[pathlib.Path]) -> pathlib.Path:
    """Write ``REPORT.md`` into ``out`` (atomically) and return its path."""
    s, v = results["settings"], results["versions"]
    lines = ["# Reproduction report", ""]
    if not results.get("complete", True):
        lines += [
            f"> **Partial result**: {len(results.get('missing', []))} of {results.get('trials_expected', '?')} trials "
            "are missing; finish the run with `--resume` on this folder.",
            "",
        ]
    n_div = len(results.get("diverged", []))
    lines += [
        "## Claims of the paper (spec section 12), judged from our numbers",
        "",
        f"Verdicts from the means over {s['seeds']} seed(s) per condition; robustness: the verdict of each seed "
        f"alone, and whether the {100 * CI_LEVEL:g}% t-interval over the seeds of each deciding quantity clears its "
        f"threshold. Diverged trials ({n_div}) are left out of every mean and claim.",
        "",
        "| claim | paper | ours | rule | verdict | robustness |",
        "|---|---|---|---|---|---|",
    ]
    lines += [
        f"| ({c['key']}) | {c['claim']} | {c['ours']} | {c['rule']} | **{c['verdict']}** | {c['robustness']} |"
        for c in results["claims"]
    ]
    lines += ["", "Each comparison, on the means and per seed:", ""] + _claims_detail(results)
    lines += [
        "",
        "## Section II: PD, location 1 (friction x perturbation level)",
        "",
        f"Means over the n trials that did not diverge; ± the {100 * CI_LEVEL:g}% t-interval of the mean.",
        "",
    ]
    lines += _phi_table(results, "pd")
    lines += ["", "Coherence minima:", ""] + _coherence_table(results, "pd")
    lines += ["", f"## Section III: IMBIC, perturbation level 1, Mhat = {s['mhat']} I kg", ""]
    lines += _phi_table(results, "imbic") + ["", "Coherence minima:", ""] + _coherence_table(results, "imbic")
    lines += ["", "## Ablation: instant samples vs interval-mean acquisition", ""] + _ablation_table(results)
    seeds = sorted(
        {(t["seed"], round(t["input_coherence_max"], 3), t["perturbation_attempt"]) for t in results["trials"]}
    )
    lines += ["", "## Perturbations", "", "| seed | max input coherence 0-15 Hz | redraws |", "|---|---|---|"]
    lines += [f"| {sd} | {coh:.3f} | {att} |" for sd, coh, att in seeds]
    diverged = results.get("diverged", [])
    lines += ["", "## Diverged trials", ""]
    lines += (
        [f"{len(diverged)} trial(s) diverged and are left out of every mean and claim: " + ", ".join(diverged)]
        if diverged
        else ["None."]
    )
    lines += ["", "## Figures", ""] + [f"![{p.stem}]({p.name})" for p in figures]
    wall = results.get("wall_s")
    lines += [
        "",
        "## Run",
        "",
        f"- settings: `{s}`",
        f"- settings key: `{results.get('key')}`",
        f"- versions: `{v}`",
        f"- trials: {len(results['trials'])} of {results.get('trials_expected', '?')}",
        f"- wall time: {wall:.1f} s" if wall else "- wall time: n/a",
    ]
    path = out / "REPORT.md"
    atomic_write_text(path, "\n".join(lines) + "\n")
    return path
