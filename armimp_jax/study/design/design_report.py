"""What ``sweeps/design_experiment.py`` says and does around ``design``: the line before it,
the design with its progress bar, the signal at the record written, the paper's perturbation
beside it, and the summary printed after.

- ``describe``: the one line said before the design starts.
- ``run_design``: ``design`` with a progress bar in steps (opened at the first step: a config
  the design refuses stays one line).
- ``at_written_record``: the result at the record the script writes (asked, the design's own,
  or the one its answer predicts), every number recomputed there.
- ``paper_reference``: per arm, the paper's perturbation at the same peak and length.
- ``summary_lines``: the criterion, the controller and minutes, the limits met, the check.
- ``robot_alone_line``: how long to record the robot alone for the arms' intervals to widen by at
  most 10% through its calibration (``bound.calibration_seconds``).
"""

from __future__ import annotations

import jax
import numpy as np

from ..._calibration.robot_calibration import RobotRecording, calibrate_robot
from ..._design.bound_design import BoundDesign
from ..._design.criterion import default_targets
from ..._design.design import design
from ..._design.record import design_lines
from ..._identification.bound import calibration_seconds, crlb
from ..._identification.layout import make_layout
from ..._identification.predict import predict_se
from ..._model.arm import no_arm
from ..._model.controllers.pd import PD
from ..._model.families import PaperNoise
from ..._model.perturbation import perturbation
from ..._simulate import make_trial
from ..runs.cli import Z95
from ..sweep.coverage import record
from . import design_check as dc
from . import design_experiment as dx


def describe(trials, family, limits, options) -> str:
    """The one line said before the design starts."""
    candidates = family if isinstance(family, list) else [family]
    what = type(candidates[0]).__name__ + (f" ({len(candidates)} candidate starts)" if len(candidates) > 1 else "")
    method = options["method"]
    bound = method if method.name == "bound" else getattr(method, "bound", None)
    monte_carlo = method if method.name == "monte_carlo" else getattr(method, "monte_carlo", None)
    how = {
        "bound": "on the Cramér-Rao bound",
        "monte_carlo": f"of {getattr(monte_carlo, 'draws', 0)} noise draws per arm",
        "auto": f"on the bound where the loops are near-linear, else of {getattr(monte_carlo, 'draws', 0)} noise "
        "draws per arm",
    }[method.name]
    gains = " and the controller's gains" if bound is not None and bound.controller else ""
    rounds = bound.calibrate if bound is not None else 0
    calibrated = f", then {rounds} round(s) of {options['steps']} calibrated through the friction" if rounds else ""
    return (
        f"designing {what}{gains} for {len(trials)} arm(s), {limits.record:g} s records, {options['steps']} steps {how}"
        f"{calibrated}"
    )


def run_design(trials, family, limits, options):
    """``design`` with a progress bar in steps (opened at the first step)."""
    from tqdm import tqdm

    bars = []

    def progress(step, steps, value):
        if not bars:
            bars.append(tqdm(total=steps, unit="step"))
        bars[0].n = step
        bars[0].set_postfix_str(f"criterion {value:.3g}", refresh=False)
        bars[0].refresh()

    try:
        return design(trials[0], family, limits=limits, progress=progress, **options)
    finally:
        for bar in bars:
            bar.close()


def targets_of(options) -> list[str]:
    """The target labels of ``options`` (the config's, or the default ones)."""
    layout = make_layout(options["free"])
    return list(options["targets"] or [layout.labels()[i] for i in default_targets(layout)])


def written_record(result, trials, settings, options, asked, design_record, precision) -> float:
    """The record [s] the design is written at: ``asked`` seconds, the design's own, or the one
    its answer predicts for ``precision`` (``design_check.predicted_record``)."""
    if asked == "design":
        return design_record
    if asked != "predicted":
        return float(asked)
    doc = dx.result_dict(result, trials, settings=settings, free=options["free"], targets=options["targets"])
    return dc.predicted_record(doc, design_record=design_record, precision=precision)


def at_written_record(result, trials, limits, settings, options, config, asked):
    """``(result at the record written, that record [s])``: the signal at the record asked, every
    number of the design recomputed there (``design_check.at_record``)."""
    precision = config["design"]["precision"]
    record = written_record(result, trials, settings, options, asked, limits.record, precision)
    signal = dc.validation_signal(result, limits, record, trials=trials, key=options["key"])
    print(f"writing the design at a {record:g} s record ({asked})", flush=True)
    at = dc.at_record(
        result,
        signal,
        trials,
        free=options["free"],
        targets=targets_of(options),
        precision=precision,
        draws=config["design"]["predict_draws"],
        key=options["key"],
    )
    return at, record


def paper_reference(result, trials, limits, options) -> list:
    """Per arm, the paper's perturbation at the same peak and length: its Cramér-Rao bound (a
    design on the bound, with the designed controller's trials) or its predicted SEs."""
    free = options["free"]
    signal = PaperNoise(limits.peak_force).signal(jax.random.key(2024), result.signal.shape[0])
    if isinstance(result, BoundDesign):
        return [crlb(t, signal, free=free, check=False) for t in trials]
    method = options["method"]
    draws = (method if method.name == "monte_carlo" else method.monte_carlo).predict_draws
    return [predict_se(t, signal, free=free, draws=draws) for t in trials]


def _limits_line(achieved: dict) -> str:
    drift = achieved.get("peak_displacement_plus_3_drift")
    return (
        f"limits met: RMS {np.round(achieved['rms_force'], 4).tolist()} N, peak "
        f"{np.round(achieved['peak_force'], 4).tolist()} N, displacement "
        f"{1e3 * achieved['peak_displacement']:.3f} mm (noise-free)"
        + ("" if drift is None else f"; with the person's own force about {1e3 * drift:.3f} mm (plus three RMS drifts)")
    )


def _validation_lines(doc: dict, precision: float) -> list[str]:
    lines = []
    if "validation" in doc:
        v = doc["validation"]
        lines.append(
            f"checked at a {v['record_s']:g} s record: RMS {np.round(v['rms_force'], 4).tolist()} N, peak "
            f"{np.round(v['peak_force'], 4).tolist()} N; the predictions made there (asked: +-{precision:.0%} at 95%)"
        )
    for row in doc["trials"]:
        if "validation" in row:
            check = row["validation"]
            spread, predicted = check["relative_spread"], check["relative_se_predicted"]
            worst = max(spread, key=spread.get)
            lines.append(
                f"{row['label']}: largest relative spread {spread[worst]:.4g} ({worst}) / largest predicted "
                f"{max(predicted.values()):.4g} = {spread[worst] / max(predicted.values()):.2f}; +-"
                f"{Z95 * spread[worst]:.1%} at 95% ({check['converged']} of {check['recordings']} recordings "
                "converged)"
            )
    return lines


def summary_lines(result, doc, config, limits) -> list[str]:
    """The criterion before and after, the controller and minutes (on the bound), the paper's
    perturbation, the limits met, and the Monte Carlo check per arm (where it ran)."""
    on_bound = isinstance(result, BoundDesign)
    what = "bound on the relative SE" if on_bound else "relative SE"
    lines = [
        f"criterion (largest {what} over targets and arms, {limits.record:g} s): start "
        f"{result.criterion_before:.4g}, designed {result.criterion_after:.4g}"
    ]
    if on_bound:
        lines.append(f"controller (each arm resolves the rest itself): {doc['controller']}")
        lines.append(
            f"the bound's minutes of the starting signal, per arm: {np.round(result.start_minutes, 2).tolist()}; drift "
            f"{1e3 * result.achieved['drift']:.3f} mm"
        )
    labels = [r["label"] for r in doc["trials"]]
    precision = config["design"]["precision"]
    lines += design_lines(result, precision, labels=labels, written_s=doc["record_s"])
    note = dx.friction_note(result) if on_bound and result.predicted_minutes is None else ""
    lines += [note] if note else []
    lines.append(f"routes: the model route, or the classical route at {doc['routes']['classical']}")
    worst_paper = max(max(row["relative_se_paper"].values()) for row in doc["trials"])
    worst = max(max(row["relative_se_after"].values()) for row in doc["trials"])
    lines.append(
        f"at the {doc['record_s']:g} s signal written, largest {what}: designed {worst:.4g}, the paper's "
        f"perturbation at the same peak and length {worst_paper:.4g}"
    )
    return lines + [_limits_line(result.achieved)] + _validation_lines(doc, precision)


ALONE_S = 8.0  # [s] the robot-alone record simulated to calibrate (the covariance then scales as 1 / T)
ALONE_PEAK = 10.0  # [N] its perturbation's peak, under PD (protocol.py's)
WIDEN = 0.10


def robot_alone_line(trials, signal, free) -> str:
    """How long to record the robot alone (under PD at ``ALONE_PEAK``) for every arm's SE bounds to
    widen by at most ``WIDEN`` through its calibration: ``ALONE_S`` of it simulated with the first
    arm's robot, friction and sensors, calibrated (``calibrate_robot``, no force: the person's
    recording tells the offset), and ``calibration_seconds`` per arm, the longest."""
    first = trials[0]
    alone = make_trial(
        PD(), arm=no_arm(first.x0), robot=first.robot, friction=first.friction, sensors=first.sensors, voluntary=None
    )
    f = perturbation(jax.random.key(70), int(round(ALONE_S / alone.period)), ALONE_PEAK)
    sim = record(alone, f, 80)
    cal = calibrate_robot(RobotRecording(x=np.asarray(sim.x), command=np.asarray(sim.fu)), robot=first.robot)
    arm_free = tuple(n for n in free if n.startswith("arm."))
    seconds = max(calibration_seconds(t, signal, cal, ALONE_S, free=arm_free, widen=WIDEN) for t in trials)
    what = f"under PD ({ALONE_PEAK:g} N peak)"
    head = (
        f"the robot alone: {seconds:.3g} s of recording {what} calibrate it"
        if seconds > ALONE_S
        else f"the robot alone: any recording {what} that calibrate_robot takes (a few seconds; {seconds:.2g} s by the "
        "bound) calibrates it"
    )
    return (
        f"{head} for every arm's SE bound to widen by at most {WIDEN:.0%} (its inertias and viscous friction; the "
        "Coulomb torque's share lies outside the bound; free sensors.force_offset: the person's recording tells it)"
    )
