"""What ``sweeps/estimate_recording.py`` prints, for both routes: one item a line.

- ``welch_report``: the Welch route (``study.recording.estimate_recording``): the fit's 95% intervals,
  the delay, VAF and lack of fit with their ``estimate_recording.verdict`` (the sentence that also titles
  ``bode.png``), the coherence summary and the warnings.
- ``model_report``: the model route (``study.recording.identify_recording``): convergence, each entry
  as value +- SE beside the classical answer, VAF, whiteness and the warnings.
- ``pooled_report``: the same for several recordings in one identification
  (``study.recording.identify_pool``): the arm's entries beside each of its group's classical answers,
  each recording's VAF and whiteness.
"""

from __future__ import annotations

import numpy as np

from .estimate_recording import PARAMETERS, coherence_summary, intervals, verdict
from .identify_pool import rows
from .identify_recording import CHANNELS, entries
from .recording_figures import AXES, ELEMENTS, OUTPUTS


def _interval_lines(fit, acquisition: str) -> list[str]:
    ci = intervals(fit)
    lines = ["95% intervals [low, high] (t quantile of each element's dof), indexed [force axis, displacement axis]:"]
    for name, unit in PARAMETERS:
        value = np.asarray(getattr(fit, name))
        lo, hi = ci[name]["low"], ci[name]["high"]
        for i, j in ELEMENTS:
            lines.append(
                f"  {name} {AXES[i]}{AXES[j]} [{unit}]: {value[i, j]:10.4g}   95% [{lo[i, j]:.4g}, {hi[i, j]:.4g}]"
            )
    if acquisition == "delay":
        d, lo, hi = (1e3 * float(np.asarray(v)) for v in (fit.delay, ci["delay"]["low"], ci["delay"]["high"]))
        lines.append(f"  force-channel delay [ms]: {d:.4g}   95% [{lo:.4g}, {hi:.4g}]")
    return lines


def _coherence_lines(est) -> list[str]:
    summary = coherence_summary(est)
    lines = []
    for field, names in OUTPUTS.items():
        for name in names:
            c = summary[f"multiple_{field}"][name]
            lines.append(
                f"coherence {name}: min {c['min']:.3f} at {c['f_at_min_hz']:.3g} Hz, median {c['median']:.3f}, "
                f"{100 * c['fraction_above_0_9']:.0f}% of bins above 0.9"
            )
    lines.append(
        f"input coherence: max {summary['inputs_max']:.3f} at {summary['inputs_f_at_max_hz']:.3g} Hz (paper's guide "
        f"0.4; independent inputs reach it by chance with p = {summary['inputs_chance_p']:.2g})"
    )
    return lines


def welch_report(
    est, fit, *, acquisition: str, warnings: list[str], friction_given: bool = True, share=None, lines: bool = False
) -> list[str]:
    """What the Welch route prints: the acquisition (and, for instant or delayed force samples
    without ``--friction``, that the robot's friction is read from the record), the 95% intervals per
    element, the fitted delay, VAF and the lack-of-fit test with their ``verdict``, the
    coherence summary and the warnings."""
    assumed = acquisition in ("instant", "delay") and not friction_given
    header = f"fit: acquisition {acquisition!r}" + (
        " (robot friction unknown: stick-slip read from the record; --friction N_M if you know it)" if assumed else ""
    )
    lof, p = float(np.asarray(fit.lack_of_fit_overall)), float(np.asarray(fit.lack_of_fit_p_overall))
    out = [header, *_interval_lines(fit, acquisition)]
    out.append(f"VAF {float(np.asarray(fit.vaf_overall)):.2f} % (the share of Z's variance the model accounts for)")
    out.append(
        f"lack of fit: residuals / the estimate's predicted noise {lof:.3g} (about 1 when the residuals are "
        f"noise alone), p = {p:.3g}"
    )
    if share is not None:
        fitted = "only those bins fitted (--lines)" if lines else "every bin fitted"
        out.append(f"the perturbation holds {share:.0%} of the band's bins on both axes; {fitted}")
    out.append("verdict: {}: {}".format(*verdict(fit, share=share, lines=lines)))
    out += _coherence_lines(est)
    return out + ([f"WARNING: {w}" for w in warnings] or ["no warnings"])


def _head(res, classical: str) -> list[str]:
    return [
        "converged" if res.converged else f"NOT CONVERGED: {res.message}",
        f"cost {res.cost:.6g} after {res.iterations} iterations, {res.time_s:.1f} s; estimates "
        "(value +- SE; 95% interval value +- 1.96 SE; arm matrices indexed [force axis, displacement axis]; "
        f"classical: {classical}):",
    ]


def _quality(fit) -> list[str]:
    """VAF and whiteness of ``fit`` (an ``Identification`` or a ``RecordingFit``), one line each."""
    vaf = np.concatenate([fit.vaf_position, fit.vaf_force])
    p = np.asarray(fit.whiteness_p)
    return [
        "VAF [%]: " + ", ".join(f"{c} {v:.2f}" for c, v in zip(CHANNELS, vaf, strict=True)),
        "residual whiteness (Ljung-Box p): " + ", ".join(f"{c} {v:.2g}" for c, v in zip(CHANNELS, p, strict=True)),
    ]


def _warning_lines(warnings: list[str]) -> list[str]:
    return [f"WARNING: {w}" for w in warnings] or ["no warnings: the fit looks sound"]


def model_report(res, classical, warnings: list[str]) -> list[str]:
    """What the model route prints: convergence, each entry of ``res`` (an ``Identification``)
    as value +- SE (with the ``classical`` fit's answer beside the arm's: the Welch route at
    its defaults, ``None`` for none), VAF, whiteness, and every warning."""
    lines = _head(res, "the Welch route's fit at its defaults")
    for e in entries(res, classical):
        beside = "" if e.classical is None else f"   (classical {e.classical:.4g})"
        lines.append(f"  {e.label} [{e.unit}]: {e.value:10.4g} +- {e.se:.3g}{beside}")
    return lines + _quality(res) + _warning_lines(warnings)


def pooled_report(res, names, classical, warnings: list[str]) -> list[str]:
    """What the pooled model route prints: convergence, each entry of ``res`` (a pooled
    ``Identification``) as value +- SE [unit] with its group (the arm's beside the classical
    answer of each of the group's recordings with an arm: ``classical``, one ``classical_fit``
    per recording, ``None`` for none), each recording's VAF and whiteness under its name
    (``names``), and every warning."""
    lines = _head(res, "the Welch route's fit at its defaults, one per recording of the group")
    for r in rows(res):
        where = f" (group {r['group']})" if r["group"] else " (shared)"
        beside = _classical_beside(res, classical, r)
        lines.append(
            f"  {r['parameter']}[{r['index']}]{where} [{r['unit']}]: {r['value']:10.4g} +- {r['se']:.3g}{beside}"
        )
    for name, fit in zip(names, res.recordings, strict=True):
        lines += [f"recording {name} (group {fit.group}): {line}" for line in _quality(fit)]
    return lines + _warning_lines(warnings)


def _classical_beside(res, classical, row) -> str:
    """``"   (classical a, b)"``: an arm entry's classical value in each recording of its group
    that has an arm (every such recording for an arm shared by all), or ``""``."""
    if not row["parameter"].startswith("arm."):
        return ""
    field, index = row["parameter"].split(".")[1], tuple(int(i) for i in row["index"].split(","))
    values = [
        float(np.asarray(getattr(cls[1], field))[index])
        for fit, cls in zip(res.recordings, classical, strict=True)
        if cls is not None and row["group"] in ("", fit.group) and np.any(np.asarray(fit.trial.arm.mass) != 0)
    ]
    return f"   (classical {', '.join(f'{v:.4g}' for v in values)})" if values else ""
