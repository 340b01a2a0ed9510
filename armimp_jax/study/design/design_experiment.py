"""Experiment design from a TOML config: the trial(s), the family, the limits, ``design``, the
designed perturbation on disk, and its check by Monte Carlo identification.

- ``read_design_config(path)``: the TOML, read and checked (``config.read_config``); every
  bad key is one ``ConfigError`` line naming it, before any simulation.
- ``build_design(config)``: the trials (the ``[arm]`` section's, or the paper's arm locations
  of ``[design] robust``), the starting family, the ``Limits`` and ``design``'s options.
- ``result_dict``: what ``design.json`` holds, with the Monte Carlo check of ``design_check``
  (the spread of ``identify``'s estimates) set against the predicted SEs.
- ``write_results``: ``perturbation.csv`` (what a robot's software loads), ``perturbation.npz``,
  ``design.json`` (strict, with the settings and the package version) and three figures.

Keys, units and defaults: docs/experiment_design.md.
"""

from __future__ import annotations

import pathlib

import jax
import numpy as np
from matplotlib.figure import Figure  # no pyplot: no global figure state

from ..._design.bound_design import BoundDesign
from ..._design.criterion import default_targets, relative_se
from ..._design.design import AGGREGATES, CRITERIA, METHODS, Auto, CramerRao, MonteCarlo
from ..._design.limits import Limits
from ..._identification.bound import has_friction
from ..._identification.layout import make_layout, parameter_units
from ..._model.families import ShapedNoise, multisine
from ...presets import arm as paper_arm
from ..recording.estimate_recording import SPARSE_SHARE, input_bins, route_settings
from ..runs.results import atomic_write_json, atomic_write_npz, atomic_write_text, package_version
from ..schema.config import REQUIRED, TRIAL_SECTIONS, ConfigError, build_trial, read_config
from ..sweep.figures import save_figure
from .design_check import truth

FAMILIES = ("shaped_noise", "multisine")
# the record the Monte Carlo check runs at: the design's own, or the one its minutes predict
WRITE_RECORDS = ("predicted", "design")  # or a number of seconds
SECTIONS = {
    **{k: v for k, v in TRIAL_SECTIONS.items()},
    "family": {
        "type": ("text", FAMILIES, "shaped_noise"),
        "low": ("scalar", "Hz", 0.5),
        "high": ("scalar", "Hz", 15.0),
        "lines": ("int", 2, 8),
        "spacing": ("text", ("linear", "log"), None),
        "duty": ("numbers", "", [1.0]),
        "burst": ("scalar", "s", 2.0),
    },
    "limits": {
        "rms_force": ("pair", "N", REQUIRED),
        "peak_force": ("pair", "N", REQUIRED),
        "record": ("scalar", "s", REQUIRED),
        "peak_displacement": ("scalar", "m", None),
        "drift": ("scalar", "m", None),
        "min_stiffness": ("scalar", "N/m", 0.0),
        "min_damping": ("scalar", "N s/m", 0.0),
    },
    "design": {
        "free": ("names", parameter_units, REQUIRED),
        "targets": ("texts", "", []),
        "criterion": ("text", CRITERIA, "max_relative_se"),
        "aggregate": ("text", AGGREGATES, "worst"),
        "method": ("text", METHODS, "auto"),
        "controller": ("text", ("fixed", "design"), "fixed"),
        "calibrate": ("int", 0, 0),
        "precision": ("scalar", "", 0.1),
        "robust": ("choices", (1, 2, 3, 4), []),
        "steps": ("int", 1, 40),
        "learning_rate": ("scalar", "", 0.15),
        "draws": ("int", 8, 16),
        "predict_draws": ("int", 8, 64),
        "seed": ("int", 0, 0),
    },
    "validate": {"seeds": ("int", 0, 0), "draws": ("int", 8, 32)},
}
REQUIRED_SECTIONS = ("controller", "friction", "limits", "design")


def read_design_config(path) -> dict:
    """The config at ``path`` as plain values, checked; ``ConfigError`` (one line) otherwise.

    The section's own rules (an arm to design for, the band, bursts only for shaped noise, a
    controller design only on the bound) are checked here; the values themselves by building
    what they describe (the starting family, the ``Limits``). ``design`` checks its options
    (targets, precision, learning rate) first thing, before any simulation. Needs float64."""
    config = read_config(path, SECTIONS, REQUIRED_SECTIONS)
    if "arm" not in config and not config["design"]["robust"]:
        raise ConfigError(f"{path}: give the arm to design for: an [arm] section or [design] robust = [1, 2, 3, 4]")
    fam = config.get("family", {k: v[2] for k, v in SECTIONS["family"].items()})
    config["family"] = fam
    if not 0 < fam["low"] < fam["high"] < 500.0:
        raise ConfigError(
            f"{path}: [family] needs 0 < low < high < 500 Hz (the control rate's Nyquist frequency), "
            f"got low {fam['low']} and high {fam['high']}"
        )
    if not (all(0 < d <= 1 for d in fam["duty"]) and fam["burst"] > 0):
        raise ConfigError(
            f"{path}: [family] duty values must lie in (0, 1] and burst > 0 s, got duty {fam['duty']} and "
            f"burst {fam['burst']}"
        )
    if fam["type"] == "multisine" and fam["duty"] != [1.0]:
        raise ConfigError(f"{path}: [family] duty (bursts) applies to type 'shaped_noise' only, got {fam['duty']}")
    for section, build in (("family", make_family), ("limits", make_limits)):
        try:
            build(config[section])
        except ValueError as err:
            raise ConfigError(f"{path}: [{section}] {err}") from None
    d = config["design"]
    if d["controller"] == "design" and d["method"] == "monte_carlo":
        raise ConfigError(f"{path}: [design] controller = 'design' needs method 'bound' or 'auto', not 'monte_carlo'")
    if d["calibrate"] and d["method"] == "monte_carlo":
        raise ConfigError(f"{path}: [design] calibrate = {d['calibrate']} weighs the bound: method 'bound' or 'auto'")
    return config


def make_limits(lim: dict) -> Limits:
    """The ``Limits`` of a config's ``[limits]`` section."""
    keys = ("peak_displacement", "drift", "min_stiffness", "min_damping")
    return Limits(lim["rms_force"], lim["peak_force"], lim["record"], **{k: lim[k] for k in keys})


def make_family(fam: dict):
    """The starting family of a config's ``[family]`` section: a ``Multisine``, a ``ShapedNoise``,
    or (several duties) a list of candidate ``ShapedNoise`` starts, ``design`` starting from the
    best. Flat, at 1 N RMS: ``design`` scales it to the limits."""
    # default spacing: a multisine's lines evenly (one per Welch bin), a shaped noise's knots in log
    spacing = fam["spacing"] or ("linear" if fam["type"] == "multisine" else "log")
    grid = (np.linspace if spacing == "linear" else np.geomspace)(fam["low"], fam["high"], fam["lines"])
    if fam["type"] == "multisine":
        return multisine(grid, 1.0, offset=0.5)
    starts = [ShapedNoise(grid, np.ones((2, fam["lines"])), 1.0, duty=d, burst=fam["burst"]) for d in fam["duty"]]
    return starts[0] if len(starts) == 1 else starts


def build_design(config: dict, *, where: str = "config") -> tuple:
    """``(trials, family, limits, options)`` of a config of ``read_design_config``; ``options``
    are ``design``'s keyword arguments (``robust_over`` included). Needs float64."""
    robust = config["design"]["robust"]
    if robust:
        trials = [build_trial(config, where=where, arm=paper_arm(loc)) for loc in robust]
    else:
        trials = [build_trial(config, where=where)]
    d = config["design"]
    options = dict(
        free=tuple(d["free"]),
        targets=d["targets"] or None,
        criterion=d["criterion"],
        aggregate=d["aggregate"],
        method=design_method(d),
        robust_over=trials,
        steps=d["steps"],
        learning_rate=float(d["learning_rate"]),
        key=jax.random.key(d["seed"]),
    )
    return trials, make_family(config["family"]), make_limits(config["limits"]), options


def design_method(d: dict):
    """The method object of a config's ``[design]`` section: ``CramerRao`` (``method = "bound"``:
    ``controller``, ``calibrate``, ``precision``, its calibrations' ``predict_draws``),
    ``MonteCarlo`` (``"monte_carlo"``: ``draws``, ``predict_draws``) or ``Auto`` of both."""
    bound = CramerRao(
        controller=d["controller"] == "design",
        calibrate=d["calibrate"],
        precision=float(d["precision"]),
        draws=d["predict_draws"],
    )
    monte_carlo = MonteCarlo(draws=d["draws"], predict_draws=d["predict_draws"])
    return {"bound": bound, "monte_carlo": monte_carlo, "auto": Auto(bound, monte_carlo)}[d["method"]]


def _validation_row(v, se, relative_value, predicted: dict, labels, scale: float) -> dict:
    """One arm's check: the spread against the predicted SEs ``se`` (already at the checked
    record) per entry, and per target the relative spread against ``predicted`` (the relative
    SEs at the design's record) times ``scale``."""
    at = {t: labels.index(t) for t in predicted}
    return dict(
        recordings=v["recordings"],
        diverged=v["diverged"],
        converged=v["converged"],
        spread=v["spread"],
        spread_over_predicted=v["spread"] / se,
        mean_error=v["mean_error"],
        relative_spread={t: v["spread"][i] / relative_value[i] for t, i in at.items()},
        relative_se_predicted={t: predicted[t] * scale for t in predicted},
    )


def friction_note(result: BoundDesign) -> str:
    """The line under a bound design's minutes when its trials have joint friction, which the
    bound leaves out (``crlb``'s reference: the loop without it); ``""`` otherwise."""
    rough = [t for t in result.trials if has_friction(t)]
    if not rough:
        return ""
    torques = [np.max(np.asarray(t.friction.tau_c)) for t in rough if hasattr(t.friction, "tau_c")]
    tau_c = f"{max(torques):g} N m" if torques else type(rough[0].friction).__name__
    if result.predicted_minutes is not None:
        return (
            f"  through the joints' Coulomb friction ({tau_c}), predict_se's minutes per arm: "
            f"{np.round(result.predicted_minutes, 2).tolist()} (the bound's leave the friction out)"
        )
    return (
        f"  (the bound's minutes leave out the joints' Coulomb friction, {tau_c} here, which adds to "
        "them; [validate] seeds = 30 measures them by identification, docs/experiment_design.md)"
    )


def sensitivity_report(trials, signal, free, percent: float, labels, *, draws: int = 64) -> list[str]:
    """How well must the lab know its robot for this design: ``identify_recording``'s
    ``sensitivity_lines`` of each arm's trial at the signal written, under its head, each arm's
    lines after its label."""
    from ..recording.identify_recording import SENSITIVITY_HEAD, sensitivity_lines

    lines = [f"{SENSITIVITY_HEAD}, at the signal written"]
    for label, trial in zip(labels, trials, strict=True):
        lines += [f"{label}:", *sensitivity_lines(trial, signal, free, percent, draws=draws)]
    return lines


def _arm_record(trial) -> dict:
    a = trial.arm
    return {k: np.asarray(getattr(a, k)) for k in ("mass", "damping", "stiffness", "endpoint")}


def _bound_rows(result, targets, paper):
    """Per arm: the bound's relative SEs before, after (and under the paper's perturbation), its
    SEs, the minutes for the design's precision, and whether the loop stayed near-linear."""
    rows = []
    for k, (b0, b1) in enumerate(zip(result.start_bounds, result.bounds)):
        row = dict(
            arm=_arm_record(result.trials[k]),
            relative_se_before=b0.relative(targets),
            relative_se_after=b1.relative(targets),
            se_after=np.concatenate([np.ravel(v) for v in b1.se.values()]),
            minutes_before=result.start_minutes[k],
            minutes_after=result.minutes[k],
            near_linear=b1.near_linear,
            nonlinearity=b1.nonlinearity,
        )
        if result.predicted_minutes is not None:  # calibrated through the friction
            ratio = dict(zip(targets, result.friction_ratio[k].tolist(), strict=True))
            row["friction_ratio"] = ratio
            row["relative_se_predicted"] = {t: row["relative_se_after"][t] * ratio[t] for t in targets}
            row["predicted_minutes"] = result.predicted_minutes[k]
        if paper is not None:
            row["relative_se_paper"] = paper[k].relative(targets)
        rows.append(row)
    return rows


def _predicted_rows(result, trials, free, targets, paper):
    rows = []
    for k, trial in enumerate(trials):
        row = dict(
            arm=_arm_record(trial),
            relative_se_before=relative_se(result.before[k], trial, free=free, targets=targets),
            relative_se_after=relative_se(result.after[k], trial, free=free, targets=targets),
            se_before=np.sqrt(np.diag(np.asarray(result.before[k].covariance))),
            se_after=np.sqrt(np.diag(np.asarray(result.after[k].covariance))),
        )
        if paper is not None:
            row["relative_se_paper"] = relative_se(paper[k], trial, free=free, targets=targets)
        rows.append(row)
    return rows


def result_dict(result, trials, *, settings: dict, free, targets, validation=None, paper=None) -> dict:
    """What ``design.json`` holds (before strict JSON conversion), for a ``Design`` (Monte Carlo)
    or a ``BoundDesign`` at the signal it writes (``design_check.at_record``): the latter adds
    the ``controller`` (the config's with the designed gains: what ``make_trial`` takes for
    every arm) and the minutes per arm. With a ``validation`` (the Monte Carlo check on that
    signal), each arm's spread against the predicted SEs, and ``"validation"`` the record,
    RMS and peak it ran at."""
    labels = make_layout(free).labels()
    targets = list(targets or [labels[i] for i in default_targets(make_layout(free))])
    on_bound = isinstance(result, BoundDesign)
    rows = _bound_rows(result, targets, paper) if on_bound else _predicted_rows(result, trials, free, targets, paper)
    signal = np.asarray(result.signal)
    for k, row in enumerate(rows):
        row["label"] = arm_labels(settings, len(rows))[k]
        if validation is not None:  # per target against predict_se's through the friction where calibrated
            predicted = row.get("relative_se_predicted", row["relative_se_after"])
            value = np.abs(truth(trials[k], free))
            row["validation"] = _validation_row(validation[k], row["se_after"], value, predicted, labels, 1.0)
    doc = {
        "settings": {**settings, "armimp_jax": package_version()},
        "method": "bound" if on_bound else "monte_carlo",
        "record_s": signal.shape[0] * trials[0].period,
        "labels": labels,
        "targets": targets,
        "criterion_before": result.criterion_before,
        "criterion_after": result.criterion_after,
        "achieved": result.achieved,
        "trace": result.trace,
        "family": dict(type=type(result.family).__name__, **_family_arrays(result.family)),
        "trials": rows,
        "routes": routes(signal, 1.0 / trials[0].period),
        "time_s": result.time_s,
    }
    if validation is not None:
        doc["validation"] = dict(
            record_s=doc["record_s"],
            rms_force=np.sqrt(np.mean(signal**2, axis=0)),
            peak_force=np.abs(signal).max(axis=0),
        )
    if on_bound:
        controller = designed_controller(settings["config"]["controller"], result.controller, trials[0])
        doc.update(controller=controller, minutes=max(result.minutes), start_minutes=max(result.start_minutes))
        if result.predicted_minutes is not None:
            doc.update(predicted_minutes=max(result.predicted_minutes))
    else:
        doc.update(improved=result.improved, skipped_steps=result.skipped, start_criteria=result.start_criteria)
    return doc


def routes(signal, fs: float) -> dict:
    """Which routes of ``estimate_recording.py`` the written ``signal`` serves: the model route
    always; the classical (Welch) route over every bin where the signal fills the band, else
    only at the bins that hold its lines (``--lines``: a multisine's), with their share."""
    welch, _, _ = route_settings(np.shape(signal)[0], fs=fs)
    holds, share = input_bins(signal, welch)
    if share >= SPARSE_SHARE:
        classical = "every Welch bin: estimate_recording.py RECORDING"
    else:
        classical = (
            f"only the {int(holds.sum())} Welch bins that hold its lines ({share:.0%} of the band's): "
            "estimate_recording.py RECORDING --lines (over every bin it cannot tell)"
        )
    return dict(model="estimate_recording.py RECORDING --model CONFIG", classical=classical, bins_share=share)


def designed_controller(config_controller: dict, record: dict, trial) -> dict:
    """The controller to build every arm's trial with: the config's ``[controller]`` with the
    designed gains (the kind's ``DESIGN_GAINS``) over it. What the kind resolves per arm at
    ``make_trial`` (IMBIC's desired inertia ``M_x(q0)``) stays unresolved, as the config had it:
    one arm's resolved value would give every other arm another loop."""
    gains = type(trial.controller).DESIGN_GAINS or ()
    given = {k: v for k, v in config_controller.items() if k != "type" and v is not None}
    return {"type": record["type"], **given} | {g: record[g] for g in gains}


def arm_labels(settings: dict, n: int) -> list[str]:
    """What every figure, table and line calls the design's arms: "arm at location L" for the
    paper's arms of ``[design] robust``, else "the [arm] section's arm"."""
    robust = settings.get("config", {}).get("design", {}).get("robust") or []
    if len(robust) == n:
        return [f"arm at location {loc}" for loc in robust]
    return ["the [arm] section's arm"] if n == 1 else [f"arm {k + 1}" for k in range(n)]


def _family_arrays(family) -> dict:
    return {k: np.asarray(v) for k, v in vars(family).items()}


def spectrum_figure(fs, start, designed, limits_band=None):
    """Amplitude spectra [N] of the start and the designed signal, per axis."""
    fig = Figure(figsize=(12, 4.5), layout="constrained")
    axes = fig.subplots(1, 2, sharey=True)
    for k, ax in enumerate(axes):
        for sig, label, style in ((start, "start", ":"), (designed, "designed", "-")):
            freq = np.fft.rfftfreq(sig.shape[0], 1.0 / fs)  # the start may be of another length
            band = freq <= (40.0 if limits_band is None else limits_band)
            amp = 2.0 * np.abs(np.fft.rfft(sig[:, k])) / sig.shape[0]
            ax.semilogy(freq[band][1:], amp[band][1:], style, lw=0.8, label=label)
        top = max(np.max(2.0 * np.abs(np.fft.rfft(sig[:, k])) / sig.shape[0]) for sig in (start, designed))
        ax.set_ylim(1e-4 * top, 2.0 * top)  # the band, not the round-off far below it
        ax.set_title(f"axis {'xy'[k]}: amplitude spectrum of F_Delta", fontsize=10)
        ax.set_xlabel("frequency [Hz]")
    axes[0].set_ylabel("amplitude [N]")
    axes[0].legend(fontsize=8)
    return fig


def se_figure(doc: dict):
    """Predicted relative SE (or its Cramér-Rao bound, for a design on the bound) of each target,
    start against design (and the paper's perturbation), per trial: bars from zero."""
    targets = doc["targets"]
    trials = doc["trials"]
    fig = Figure(figsize=(max(7.0, 1.2 * len(targets) + 3), 3.2 * len(trials)), layout="constrained")
    axes = np.atleast_1d(fig.subplots(len(trials), 1, sharex=True))
    x = np.arange(len(targets))
    kinds = [("relative_se_before", "start"), ("relative_se_after", "designed")]
    if "relative_se_paper" in trials[0]:
        kinds.insert(0, ("relative_se_paper", "paper's perturbation"))
    width = 0.8 / len(kinds)
    for ax, row, k in zip(axes, trials, range(len(trials))):
        for j, (key, label) in enumerate(kinds):
            ax.bar(x + (j - (len(kinds) - 1) / 2) * width, [row[key][t] for t in targets], width, label=label)
        ax.set_ylabel("bound on SE / |value|" if doc.get("method") == "bound" else "predicted SE / |value|")
        ax.set_title(row["label"], fontsize=10)
        ax.set_ylim(bottom=0.0)
    axes[0].legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
    axes[-1].set_xticks(x, targets, rotation=30, ha="right", fontsize=8)
    return fig


def trace_figure(fs, signal, limits: Limits, trace, *, on_bound: bool = False):
    """The designed F_Delta per axis against time with the peak and RMS limits drawn, and the
    criterion over the optimisation steps."""
    fig = Figure(figsize=(12, 7), layout="constrained")
    axes = fig.subplots(3, 1)
    t = np.arange(signal.shape[0]) / fs
    peak = np.broadcast_to(np.asarray(limits.peak_force, dtype=float), (2,))
    rms = np.broadcast_to(np.asarray(limits.rms_force, dtype=float), (2,))
    for k in range(2):
        ax = axes[k]
        ax.plot(t, signal[:, k], lw=0.5, label="designed F_Delta")
        ax.axhline(peak[k], color="r", lw=1, label="peak limit")
        ax.axhline(-peak[k], color="r", lw=1)
        ax.axhline(rms[k], color="k", ls="--", lw=0.8, label="RMS limit")
        ax.axhline(-rms[k], color="k", ls="--", lw=0.8)
        ax.set_ylabel(f"F_Delta {'xy'[k]} [N]")
    axes[0].legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
    axes[1].set_xlabel("time [s]")
    axes[2].plot(np.arange(1, len(trace) + 1), trace, "o-", ms=3)
    axes[2].set_xlabel("optimisation step")
    # the bound's criterion is deterministic; the Monte Carlo one is of that step's noise draws
    axes[2].set_ylabel("criterion (the bound)" if on_bound else "criterion (that step's draws)")
    axes[2].set_ylim(bottom=0.0)
    return fig


def minutes_figure(doc: dict, precision: float):
    """Bars per arm: the bound's minutes of recording for +-``precision`` at 95% on every target,
    at the start and with the design (and, calibrated, ``predict_se``'s through the friction)."""
    rows = doc["trials"]
    fig = Figure(figsize=(6.5, 3.6), layout="constrained")
    ax = fig.subplots()
    x = np.arange(len(rows))
    bars = [("minutes_before", "start (bound)"), ("minutes_after", "designed (bound)")]
    if "predicted_minutes" in rows[0]:
        bars.append(("predicted_minutes", "designed, through the friction (predict_se)"))
    width = 0.8 / len(bars)
    for j, (key, label) in enumerate(bars):
        drawn = ax.bar(x + (j - (len(bars) - 1) / 2) * width, [r[key] for r in rows], width, label=label)
        ax.bar_label(drawn, fmt="%.2g", fontsize=7)  # the short bars' values, which the axis squashes
    ax.set_xticks(x, [r["label"] for r in rows], fontsize=8)
    ax.set_ylabel("minutes of recording")
    ax.set_title(f"minutes for +-{precision:.0%} at 95% on every target", fontsize=10)
    ax.set_ylim(bottom=0.0)
    ax.legend(fontsize=8)
    return fig


def write_results(out_dir, result, trials, limits: Limits, *, doc: dict) -> list[pathlib.Path]:
    """``perturbation.csv`` (header ``f_delta_x,f_delta_y``, one row per 1 ms sample [N]: the
    signal at the record written, what the robot's software loads), ``perturbation.npz``,
    ``design.json`` (``doc``, strict JSON) and ``spectrum.png``, ``se.png``, ``trace.png`` (and,
    for a ``BoundDesign``, ``minutes.png``) under ``out_dir``, each atomically; returns their
    paths."""
    out_dir = pathlib.Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    fs = 1.0 / trials[0].period
    csv = _write_csv(out_dir / "perturbation.csv", result.signal)
    npz = atomic_write_npz(
        out_dir / "perturbation.npz", f_delta=result.signal, fs_hz=fs, **_family_arrays(result.family)
    )
    json_path = out_dir / "design.json"
    atomic_write_json(json_path, doc)
    figures = {
        "spectrum.png": spectrum_figure(fs, result.start_signal, result.signal),
        "se.png": se_figure(doc),
        "trace.png": trace_figure(fs, result.signal, limits, result.trace, on_bound=isinstance(result, BoundDesign)),
    }
    if isinstance(result, BoundDesign):
        figures["minutes.png"] = minutes_figure(doc, doc["settings"]["config"]["design"]["precision"])
    return [csv, npz, json_path] + [save_figure(fig, out_dir / name) for name, fig in figures.items()]


def _write_csv(path, signal) -> pathlib.Path:
    """``f_delta_x,f_delta_y`` [N], one row per sample, atomically."""
    rows = "\n".join(f"{a:.17g},{b:.17g}" for a, b in np.asarray(signal))
    atomic_write_text(path, "f_delta_x,f_delta_y\n" + rows + "\n")
    return pathlib.Path(path)
