"""The fitted ``M, B, K`` part of ``REPORT.md``: the per-condition error table, the key
conditions element by element, and what the fits say about the sampled-data bias of
instant acquisition.

"Mean" in this part is always the mean over seeds; the acquisition is named in words
(``ACQUISITION``), never shortened to "mean", so an interval-mean fit is not read as a
seed-mean fit or the other way round.
"""

from __future__ import annotations

import numpy as np

from ..study.sweep.stats import CI_LEVEL
from ._text import DASH, mean_pm, times

UNITS = dict(M="kg", B="N s/m", K="N/m")
ACQUISITION = dict(instant="instant samples", interval_mean="interval-mean acquisition")
NO_FIT = "(these results hold no fitted matrices: written by an older armimp_jax; rerun the command on this folder)"


def _label(k: dict) -> str:
    """``"pd-L1-F0-P1"``: experiment, location, friction level, perturbation level."""
    return f"{k['experiment']}-L{k['location']}-F{k['friction']}-P{k['perturbation']}"


def _has_fit(c) -> bool:
    return c.get("fit_M") is not None and c.get("truth") is not None


def _element_errors(c, sym):
    """Signed relative error per element ``(fit - true) / |true|`` (NaN where the truth is 0)
    and the index of the element with the largest error relative to ``||true||_F``."""
    fit, true = np.asarray(c[f"fit_{sym}"], dtype=float), np.asarray(c["truth"][sym], dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.where(true != 0, (fit - true) / np.abs(true), np.nan)
    worst = np.unravel_index(np.nanargmax(np.abs(fit - true)), (2, 2))
    return rel, worst


def _worst_element(c) -> str:
    """The element (of M, B, K) farthest from the truth relative to its matrix's norm."""
    best = None
    for sym in UNITS:
        fit, true = np.asarray(c[f"fit_{sym}"], dtype=float), np.asarray(c["truth"][sym], dtype=float)
        share = np.abs(fit - true) / np.linalg.norm(true)
        i, j = np.unravel_index(np.nanargmax(share), (2, 2))
        if best is None or share[i, j] > best[0]:
            best = (share[i, j], sym, i, j, fit[i, j], true[i, j])
    _, sym, i, j, a, b = best
    rel = f" ({100 * (a - b) / abs(b):+.0f}%)" if b else ""
    return f"{sym}{i + 1}{j + 1} = {a:.3g} vs {b:.3g}{rel}"


def _pct(c, name) -> str:
    return mean_pm(times(100, c.get(name)), times(100, c.get(name + "_ci")), ".1f")


def _fit_table(results) -> list[str]:
    rows = [c for c in results["conditions"] if c.get("truth") is not None or "fit_M" in c]
    if not rows or not any(_has_fit(c) for c in rows):
        return [NO_FIT]
    lines = [
        "| condition | n | M rel. error | B rel. error | K rel. error | VAF [%] | "
        "farthest element of the fit (fit vs true) |",
        "|---|---|---|---|---|---|---|",
    ]
    for c in rows:
        k = c["condition"]
        label = _label(k) + ("" if k["acquisition"] == "instant" else f" ({ACQUISITION[k['acquisition']]})")
        if not _has_fit(c) or c["n"] == 0:
            lines.append(f"| {label} | {c['n']} | {DASH} | {DASH} | {DASH} | {DASH} | {DASH} |")
            continue
        errors = " | ".join(_pct(c, f"fit_{sym}_rel_error") + "%" for sym in UNITS)
        vaf = mean_pm(c["fit_vaf"], c.get("fit_vaf_ci"), ".1f")
        lines.append(f"| {label} | {c['n']} | {errors} | {vaf} | {_worst_element(c)} |")
    return lines


def _find(results, experiment, location, friction, perturbation, acquisition):
    want = dict(
        experiment=experiment,
        controller=experiment,
        location=location,
        friction=friction,
        perturbation=perturbation,
        acquisition=acquisition,
    )
    c = next((c for c in results["conditions"] if c["condition"] == want), None)
    return c if c is not None and _has_fit(c) and c["n"] > 0 else None


def _key_conditions(results) -> list[tuple[str, dict]]:
    """The frictionless PD pair (instant samples, interval means) and PD and IMBIC at the most
    friction, each named with its acquisition."""
    conds = [c["condition"] for c in results["conditions"]]
    fr_max = max((k["friction"] for k in conds), default=0)
    p_min = min((k["perturbation"] for k in conds if k["experiment"] == "pd"), default=1)
    picks = [
        ("pd", 1, 0, p_min, "instant"),
        ("pd", 1, 0, p_min, "interval_mean"),
        ("pd", 1, fr_max, p_min, "instant"),
        ("imbic", 1, fr_max, 1, "instant"),
    ]
    out = []
    for exp, loc, fr, pert, acq in dict.fromkeys(picks):
        c = _find(results, exp, loc, fr, pert, acq)
        if c is not None:
            out.append((f"{_label(c['condition'])}, {ACQUISITION[acq]}", c))
    return out


def _fit_detail(results) -> list[str]:
    picked = _key_conditions(results)
    if not picked:
        return []
    lines = [
        "",
        f"Key conditions, element by element: each *fit* is the fitted value averaged over the seeds ± its "
        f"{100 * CI_LEVEL:g}% CI; *err* is that average's relative error (fit - true) / |true|:",
        "",
        "| element | true | " + " | ".join(f"{name}: fit | err" for name, _ in picked) + " |",
        "|---|---|" + "---|---|" * len(picked),
    ]
    for sym, unit in UNITS.items():
        for i in range(2):
            for j in range(2):
                true = picked[0][1]["truth"][sym][i][j]
                cells = []
                for _, c in picked:
                    ci = c.get(f"fit_{sym}_ci")
                    rel, _ = _element_errors(c, sym)
                    cells.append(mean_pm(c[f"fit_{sym}"][i][j], None if ci is None else ci[i][j], ".3g"))
                    cells.append(DASH if np.isnan(rel[i, j]) else f"{100 * rel[i, j]:+.1f}%")
                lines.append(f"| {sym}{i + 1}{j + 1} [{unit}] | {true:.3g} | " + " | ".join(cells) + " |")
    return lines


# --- the sampled-data bias, from the fits ----------------------------------------------------


def _acquisition_pairs(results) -> list[tuple[dict, dict, dict]]:
    """``(condition, instant entry, interval-mean entry)`` for each condition fitted both ways."""
    pairs = []
    for c in results["conditions"]:
        k = c["condition"]
        if k["acquisition"] != "instant" or not _has_fit(c) or c["n"] == 0:
            continue
        twin = _find(results, k["experiment"], k["location"], k["friction"], k["perturbation"], "interval_mean")
        if twin is not None:
            pairs.append((k, c, twin))
    return pairs


def _describe(c) -> str:
    """``"B is off by 4.1% (B_11 = ...), M by ... and K by ... (VAF ...)"`` of one entry."""
    rel, (i, j) = _element_errors(c, "B")
    element = f"B_{i + 1}{j + 1} = {c['fit_B'][i][j]:.2f} vs true {c['truth']['B'][i][j]:.2f} N s/m"
    if not np.isnan(rel[i, j]):
        element += f", {100 * rel[i, j]:+.1f}%"
    return (
        f"B is off by {100 * c['fit_B_rel_error']:.1f}% ({element}), M by {100 * c['fit_M_rel_error']:.1f}% "
        f"and K by {100 * c['fit_K_rel_error']:.1f}% (VAF {c['fit_vaf']:.1f}%)"
    )


def _bias_verdict(ins, mean) -> str:
    """What the example pair says about the damping: biased by instant samples, or not."""
    others = max(ins["fit_M_rel_error"], ins["fit_K_rel_error"])
    if ins["fit_B_rel_error"] > 2 * max(mean["fit_B_rel_error"], others):
        return (
            " Instant sampling biases mainly the damping (the part of Z in phase with velocity), and "
            "interval-mean acquisition removes most of that bias."
        )
    if ins["fit_B_rel_error"] > mean["fit_B_rel_error"]:
        return " Interval-mean acquisition reduces the damping bias of instant sampling."
    return (
        " Each acquisition fitted with its own sampled-data model gives about the same damping error: the model "
        "accounts for the instant samples' lag (fitting M s^2 + B s + K to instant samples biases B instead)."
    )


def _fit_bias(results) -> str:
    """What the fits say about the sampled-data bias of instant acquisition, from the numbers:
    the frictionless PD pair (else the first pair) in detail, and the median over all pairs."""
    pairs = _acquisition_pairs(results)
    if not pairs:
        return "(no instant / interval-mean pairs with fits: the ablation was not run, or its trials diverged)"
    frictionless = [p for p in pairs if p[0]["experiment"] == "pd" and p[0]["friction"] == 0]
    k, ins, mean = min(frictionless or pairs, key=lambda p: (p[0]["perturbation"], p[0]["location"]))
    name = f"{k['experiment'].upper()}, location {k['location']}, friction {k['friction']}"
    name += f", perturbation {k['perturbation']}"
    b_ins = np.median([p[1]["fit_B_rel_error"] for p in pairs])
    b_mean = np.median([p[2]["fit_B_rel_error"] for p in pairs])
    return (
        f"Sampled-data bias, from the fitted matrices ({name}; means over {ins['n']} seed(s) with instant samples "
        f"and {mean['n']} with interval means; errors are ||fit - true||_F / ||true||_F): with instant acquisition "
        f"{_describe(ins)}; with interval-mean acquisition {_describe(mean)}."
        f" Over the {len(pairs)} condition(s) of the ablation the median B error is {100 * b_ins:.1f}% with instant "
        f"samples and {100 * b_mean:.1f}% with interval means." + _bias_verdict(ins, mean)
    )


def fits_section(results: dict) -> list[str]:
    """The report's section on the fitted ``M, B, K`` (lines of Markdown)."""
    ci = f"{100 * CI_LEVEL:g}%"
    intro = (
        "Per trial, `fit_impedance` fits the model of the trial's acquisition to the estimate (instant samples: "
        "Z(s) = M s (1 - exp(-s L)) / L + B s + K, the hold's half-sample lag on the mass term; interval means: "
        "M s^2 + B s + K; docs/estimation.md), with uniform weights. Per condition the table gives the mean over "
        "the seeds that did not diverge of each matrix's relative error ||fit - true||_F / ||true||_F (± the "
        f"{ci} t-interval), of the fit's overall VAF, and the element of the seed-averaged fit farthest from the "
        "truth relative to its matrix's norm (with its own relative error)."
    )
    lines = ["## Fitted M, B, K (least squares on each trial's estimate of Z)", "", intro, ""]
    return lines + _fit_table(results) + _fit_detail(results) + ["", _fit_bias(results)]
