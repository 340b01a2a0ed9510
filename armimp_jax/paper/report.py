"""The Markdown report of a reproduction run, written from ``results.json`` alone.

Numbers are means over the seeds whose trial did not diverge; ``±`` is the half-width of
the 95% t-interval of the mean (none with one seed); ``n`` counts the trials averaged and
``diverged`` those left out. Missing values (a condition whose every trial diverged) show
as ``—``. Conditions are named ``experiment-L<location>-F<friction level>-P<perturbation
level>``; the acquisition is named in words wherever it is not instant samples.

Sections: the claims (``_report_claims``), the paper's sections II and III and the
acquisition ablation (here), the fitted ``M, B, K`` (``_report_fits``), the perturbations,
the diverged trials, the figures and the run.
"""

from __future__ import annotations

import pathlib

from ..study.runs.results import atomic_write_text
from ..study.sweep.metrics import LOW_BAND_HZ
from ..study.sweep.stats import CI_LEVEL
from ._report_claims import claims_section
from ._report_fits import fits_section
from ._text import DASH, mean_pm, num, short, times


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
        "| location | friction | perturbation | n | phi_T [N/m] | phi_11 [N/m] | phi_12 [N/m] | phi_21 [N/m] | "
        "phi_22 [N/m] | phi_T / mean ‖Z_h‖ | mean abs. phase error [deg] | diverged |",
        "|" + "---|" * 12,
    ]
    lines = []
    for c in rows:
        k = c["condition"]
        pij = c["phi_ij"] if c["phi_ij"] is not None else [[None, None], [None, None]]
        rel = (
            DASH
            if c["rel_error"] is None
            else mean_pm(100 * c["rel_error"], times(100, c.get("rel_error_ci")), ".1f") + "%"
        )
        phase = mean_pm(c["phase_error_deg"], c.get("phase_error_deg_ci"), ".1f")
        lines.append(
            f"| {k['location']} | {k['friction']} | {k['perturbation']} | {c['n']} | "
            f"{mean_pm(c['phi_T'], c.get('phi_T_ci'))} | {num(pij[0][0])} | {num(pij[0][1])} | {num(pij[1][0])} | "
            f"{num(pij[1][1])} | {rel} | {phase} | {c['diverged']} |"
        )
    return head + lines


COHERENCES = (  # (metric, column) of the coherence table; each metric ends in _min_low or _min_high
    ("coh_multiple_x_min_low", "multiple, x"),
    ("coh_multiple_x_min_high", "multiple, x"),
    ("coh_partial_x_min_low", "partial, x"),
    ("coh_partial_x_min_high", "partial, x"),
    ("coh_multiple_fh_min_low", "multiple, F_h"),
    ("coh_multiple_fh_min_high", "multiple, F_h"),
)


def _coherence_table(results, experiment) -> list[str]:
    rows = _conds(results, experiment)
    if not rows:
        return ["(no trials)"]
    fmax = results["settings"].get("fmax")
    high = f"{LOW_BAND_HZ:g}-{fmax:g} Hz" if fmax else f"f >= {LOW_BAND_HZ:g} Hz"
    bands = dict(low=f"f < {LOW_BAND_HZ:g} Hz", high=high)
    columns = [f"{what}, {bands[name.rsplit('_', 1)[1]]}" for name, what in COHERENCES]
    head = ["| location | friction | perturbation | " + " | ".join(columns) + " |", "|" + "---|" * 9]
    lines = [
        f"| {c['condition']['location']} | {c['condition']['friction']} | {c['condition']['perturbation']} | "
        + " | ".join(mean_pm(c[n], c.get(n + "_ci"), ".3f", short) for n, _ in COHERENCES)
        + " |"
        for c in rows
    ]
    return head + lines


def _coherence_caption() -> list[str]:
    return [
        "",
        "Lowest coherence in each band: per trial the minimum over the band's frequency bins and both outputs "
        "(partial coherence: and both inputs), then the mean over the seeds ± its "
        f"{100 * CI_LEVEL:g}% t-interval.",
        "",
    ]


def _ablation_pairs(results) -> list[tuple[dict, float, float]]:
    """``(condition, phi_T instant, phi_T interval mean)`` for each condition run both ways."""
    pairs = []
    for c in results["conditions"]:
        k = c["condition"]
        if k["acquisition"] != "instant":
            continue
        twin = next((d for d in results["conditions"] if d["condition"] == dict(k, acquisition="interval_mean")), None)
        if twin and c["phi_T"] is not None and twin["phi_T"] is not None:
            pairs.append((k, c["phi_T"], twin["phi_T"]))
    return pairs


def _friction_effect(results, acquisition) -> tuple[float, float] | None:
    """phi_T of PD (location 1, perturbation 1) at friction 2 over and minus friction 0."""
    sel = {
        d["condition"]["friction"]: d["phi_T"]
        for d in results["conditions"]
        if d["condition"]["experiment"] == "pd"
        and d["condition"]["acquisition"] == acquisition
        and d["condition"]["perturbation"] == 1
        and d["phi_T"] is not None
    }
    if 0 not in sel or 2 not in sel:
        return None
    return sel[2] / sel[0], sel[2] - sel[0]


def _ablation_table(results) -> list[str]:
    pairs = _ablation_pairs(results)
    if not pairs:
        return ["(the ablation was not run, or its trials diverged)"]
    lines = [
        "| experiment | location | friction | perturbation | phi_T, instant samples [N/m] | "
        "phi_T, interval means [N/m] | interval means / instant samples |",
        "|" + "---|" * 7,
    ]
    lines += [
        f"| {k['experiment']} | {k['location']} | {k['friction']} | {k['perturbation']} | {a:.0f} | {b:.0f} | "
        f"{b / a:.2f} |"
        for k, a, b in pairs
    ]
    ins, mean = _friction_effect(results, "instant"), _friction_effect(results, "interval_mean")
    if ins and mean and ins[1] > 0:  # a share of the friction-caused increase needs an increase
        (ri, di), (rm, dm) = ins, mean
        lines += [
            "",
            f"PD, location 1, perturbation 1: friction 2 raises phi_T {ri:.1f}x (by {di:.0f} N/m) with "
            f"instant sampling and {rm:.1f}x (by {dm:.0f} N/m) with interval means: "
            f"{100 * dm / di:.1f}% of the friction-caused increase survives anti-aliased acquisition.",
        ]
    return lines


def _paper_sections(results) -> list[str]:
    """The paper's sections II (PD) and III (IMBIC) and the acquisition ablation."""
    ci = f"{100 * CI_LEVEL:g}%"
    return [
        "",
        "## The paper's section II: PD, location 1 (friction x perturbation level)",
        "",
        f"Means over the n trials that did not diverge; ± the {ci} t-interval of the mean (phi_T, the relative "
        "error and the phase error; phi_ij: means only). phi_T / mean ‖Z_h‖: phi_T over the mean largest singular "
        "value of the true impedance; the phase error is the mean over bins and elements of |phase(Z / Z_h)|.",
        "",
        *_phi_table(results, "pd"),
        *_coherence_caption(),
        *_coherence_table(results, "pd"),
        "",
        f"## The paper's section III: IMBIC, perturbation level 1, Mhat = {results['settings']['mhat']} I kg",
        "",
        *_phi_table(results, "imbic"),
        *_coherence_caption(),
        *_coherence_table(results, "imbic"),
        "",
        "## Ablation: instant samples vs interval-mean acquisition",
        "",
        *_ablation_table(results),
    ]


def _perturbations(results) -> list[str]:
    fmax = results["settings"].get("fmax")
    band = f"0-{fmax:g} Hz" if fmax else "the estimation band"
    seeds = sorted(
        {(t["seed"], round(t["input_coherence_max"], 3), t["perturbation_attempt"]) for t in results["trials"]}
    )
    return [
        "",
        "## Perturbations",
        "",
        f"Per seed: the largest coherence between the two perturbation axes over {band} (the paper kept it "
        "below 0.4), and how many times the perturbation was drawn again to get under the run's cap.",
        "",
        "| seed | max input coherence | redraws |",
        "|---|---|---|",
        *(f"| {sd} | {short(coh, '.3f')} | {att} |" for sd, coh, att in seeds),
    ]


def _diverged(results) -> list[str]:
    diverged = results.get("diverged", [])
    text = (
        f"{len(diverged)} trial(s) diverged and are left out of every mean and claim: " + ", ".join(diverged)
        if diverged
        else "None."
    )
    return ["", "## Diverged trials", "", text]


def _run(results) -> list[str]:
    wall = results.get("wall_s")
    wall_text = (
        f"{wall:.1f} s, as recorded in `run.json` (`wall_s`): simulating the trials, aggregating and drawing the "
        "figures, summed over every command that worked on this folder"
        if wall
        else "not recorded"
    )
    return [
        "",
        "## Run",
        "",
        f"- settings: `{results['settings']}`",
        f"- settings key: `{results.get('key')}`",
        f"- versions: `{results['versions']}`",
        f"- trials: {len(results['trials'])} of {results.get('trials_expected', '?')}",
        f"- wall time: {wall_text}",
    ]


def _partial(results) -> list[str]:
    if results.get("complete", True):
        return []
    return [
        f"> **Partial result**: {len(results.get('missing', []))} of {results.get('trials_expected', '?')} trials "
        "are missing; finish the run with `--resume` on this folder.",
        "",
    ]


def _naming() -> list[str]:
    return [
        "Conditions are named `experiment-L<location>-F<friction level>-P<perturbation level>` (e.g. "
        "`pd-L1-F0-P1`: PD, arm location 1, no friction, perturbation level 1); trial ids add `-mean` for "
        "interval-mean acquisition and `-S<seed>`. Arm locations are the paper's Table 2, friction levels its "
        "Table 1 (0: none), perturbation levels its Table 3 (1: the smallest).",
        "",
    ]


def report_text(results: dict, out: pathlib.Path, figures: list[pathlib.Path]) -> str:
    """The text of ``REPORT.md`` for ``results`` (``aggregate``'s); ``out`` is the folder it
    goes into (for relative links), ``figures`` the images to show."""
    lines = ["# Reproduction report", "", *_partial(results), *_naming(), *claims_section(results, out)]
    lines += _paper_sections(results)
    lines += ["", *fits_section(results)]
    lines += _perturbations(results) + _diverged(results)
    lines += ["", "## Figures", "", *(f"![{p.stem}]({p.name})" for p in figures)]
    lines += _run(results)
    return "\n".join(lines) + "\n"


def write_report(results: dict, out: pathlib.Path, figures: list[pathlib.Path]) -> pathlib.Path:
    """Write ``REPORT.md`` into ``out`` (atomically) and return its path."""
    path = out / "REPORT.md"
    atomic_write_text(path, report_text(results, out, figures))
    return path
