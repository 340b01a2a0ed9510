"""Design the perturbation of an impedance experiment within a patient's limits, and check it.

    python sweeps/design_experiment.py CONFIG.toml --out DIR [--record predicted|design|SECONDS] [--validate SEEDS]
        [--sensitivity PERCENT]

CONFIG.toml names the robot, controller, sensors, the person's own force and the friction
(as the model route of estimate_recording.py), the arm to design for ([arm], or the
paper's arm locations in [design] robust), the perturbation family ([family]: shaped
noise or a multisine over a band), the limits ([limits]: RMS and peak force per axis [N],
peak hand displacement [m], record length [s]) and what to minimise ([design]: the free
parameters, the target entries, the criterion). Keys, units and defaults:
docs/experiment_design.md; an example: sweeps/configs/design_example.toml.

Writes DIR/perturbation.csv (f_delta_x, f_delta_y [N], one row per 1 ms: what the robot's
software loads) at the record --record names: by default the one the design's own minutes
predict for its precision (rounded up to a second, never below [limits] record), or the
design's own record, or SECONDS (the family's signal at that length, within the same
limits). DIR/design.json holds every number at that signal, on the designed controller (the
bound of each arm, the minutes, predict_se's through the friction where calibrated, the
limits met), with the settings, the start and the optimisation trace; DIR/perturbation.npz,
DIR/spectrum.png, DIR/se.png, DIR/trace.png (and minutes.png) beside it. With --validate
SEEDS (or [validate] seeds) it simulates and identifies SEEDS recordings per arm under new
noise with that signal and reports the spread of the estimates against the predicted SEs.
With --sensitivity PERCENT it prints, per arm, how far a PERCENT error in each of the robot's
parameters would move each arm entry in SEs, with a warning where that is more than one.
A bound's minutes leave the joints' friction out: calibrate ([design] calibrate) before
trusting them through friction. Every bad config gets one line on stderr and exit status 2,
before any computation.
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import time

from armimp_jax.study.cli import Z95, Parser, error_line

PROG = "design_experiment"


def parse(argv):
    ap = Parser(prog=PROG, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("config", type=pathlib.Path, help="TOML config (see above)")
    ap.add_argument("--out", type=pathlib.Path, required=True, metavar="DIR", help="output folder (created)")
    ap.add_argument(
        "--record",
        default="predicted",
        metavar="{predicted,design,SECONDS}",
        help="the written signal's record: the one the design predicts (default), its own, or SECONDS",
    )
    ap.add_argument("--validate", type=int, metavar="SEEDS", help="Monte Carlo check: recordings per arm")
    ap.add_argument(
        "--sensitivity",
        type=float,
        metavar="PERCENT",
        help="also print how far a PERCENT error in each robot parameter (inertia, friction, force gain; 1 ms of "
        "force delay) would move each arm entry, in SEs (armimp_jax.robot_sensitivity per arm)",
    )
    args = ap.parse_args(argv)
    if args.sensitivity is not None and not 0 < args.sensitivity <= 100:
        ap.error(f"--sensitivity takes a percentage in (0, 100], got {args.sensitivity:g}")
    if args.validate is not None and args.validate < 0:
        ap.error(f"--validate must be >= 0 recordings, got {args.validate}")
    if args.record not in ("predicted", "design"):
        try:
            args.record = float(args.record)
        except ValueError:
            ap.error(f"--record must be predicted, design or a number of seconds, got {args.record!r}")
        if not args.record >= 2.0:
            ap.error(f"--record must be >= 2 s, got {args.record:g}")
    return args


def fail(message: str) -> int:
    return error_line(message, PROG)


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


def run_design(aj, trials, family, limits, options):
    """``aj.design`` with a progress bar in steps (opened at the first step: a config the design
    refuses stays one line)."""
    from tqdm import tqdm

    bars = []

    def progress(step, steps, value):
        if not bars:
            bars.append(tqdm(total=steps, unit="step"))
        bars[0].n = step
        bars[0].set_postfix_str(f"criterion {value:.3g}", refresh=False)
        bars[0].refresh()

    try:
        return aj.design(trials[0], family, limits=limits, progress=progress, **options)
    finally:
        for bar in bars:
            bar.close()


def paper_reference(aj, jax, result, trials, limits, options) -> list:
    """Per arm, the paper's perturbation at the same peak and length: its Cramér-Rao bound (a
    design on the bound, with the designed controller's trials) or its predicted SEs."""
    free = options["free"]
    signal = aj.PaperNoise(limits.peak_force).signal(jax.random.key(2024), result.signal.shape[0])
    if isinstance(result, aj.BoundDesign):
        return [aj.crlb(t, signal, free=free, check=False) for t in trials]
    method = options["method"]
    draws = (method if method.name == "monte_carlo" else method.monte_carlo).predict_draws
    return [aj.predict_se(t, signal, free=free, draws=draws) for t in trials]


def print_summary(np, result, doc, config, limits, *, on_bound: bool) -> None:
    """The criterion before and after, the controller and minutes (on the bound), the paper's
    perturbation, the limits met, and the Monte Carlo check per arm (where it ran)."""
    what = "bound on the relative SE" if on_bound else "relative SE"
    print(
        f"criterion (largest {what} over targets and arms, {limits.record:g} s): start "
        f"{result.criterion_before:.4g}, designed {result.criterion_after:.4g}"
    )
    if on_bound:
        print(f"controller (each arm resolves the rest itself): {doc['controller']}")
        print(
            f"the bound's minutes of the starting signal, per arm: {np.round(result.start_minutes, 2).tolist()}; drift "
            f"{1e3 * result.achieved['drift']:.3f} mm"
        )
    from armimp_jax.study.design_experiment import design_lines, friction_note

    labels = [r["label"] for r in doc["trials"]]
    print("\n".join(design_lines(result, config["design"]["precision"], labels=labels, written_s=doc["record_s"])))
    if on_bound and result.predicted_minutes is None:
        note = friction_note(result)
        if note:
            print(note)
    print(f"routes: the model route, or the classical route at {doc['routes']['classical']}")
    worst_paper = max(max(row["relative_se_paper"].values()) for row in doc["trials"])
    worst = max(max(row["relative_se_after"].values()) for row in doc["trials"])
    print(
        f"at the {doc['record_s']:g} s signal written, largest {what}: designed {worst:.4g}, the paper's "
        f"perturbation at the same peak and length {worst_paper:.4g}"
    )
    print(
        f"limits met: RMS {np.round(result.achieved['rms_force'], 4).tolist()} N, peak "
        f"{np.round(result.achieved['peak_force'], 4).tolist()} N, displacement "
        f"{1e3 * result.achieved['peak_displacement']:.3f} mm (noise-free)"
        + (
            f"; with the person's own force about {1e3 * result.achieved['peak_displacement_plus_3_drift']:.3f} mm "
            "(plus three RMS drifts)"
            if "peak_displacement_plus_3_drift" in result.achieved
            else ""
        )
    )
    if "validation" in doc:
        v, p = doc["validation"], config["design"]["precision"]
        print(
            f"checked at a {v['record_s']:g} s record: RMS {np.round(v['rms_force'], 4).tolist()} N, peak "
            f"{np.round(v['peak_force'], 4).tolist()} N; the predictions made there (asked: +-{p:.0%} at 95%)"
        )
    for k, row in enumerate(doc["trials"]):
        if "validation" in row:
            check = row["validation"]
            spread, predicted = check["relative_spread"], check["relative_se_predicted"]
            worst = max(spread, key=spread.get)
            print(
                f"{row['label']}: largest relative spread {spread[worst]:.4g} ({worst}) / largest predicted "
                f"{max(predicted.values()):.4g} = {spread[worst] / max(predicted.values()):.2f}; +-"
                f"{Z95 * spread[worst]:.1%} at 95% ({check['converged']} of {check['recordings']} recordings "
                "converged)"
            )


def targets_of(dx, options) -> list[str]:
    """The target labels of ``options`` (the config's, or the default ones)."""
    from armimp_jax.study.design_experiment import default_targets, make_layout

    layout = make_layout(options["free"])
    return list(options["targets"] or [layout.labels()[i] for i in default_targets(layout)])


def written_record(dc, dx, result, trials, settings, options, asked, design_record, precision) -> float:
    """The record [s] the design is written at: ``asked`` seconds, the design's own, or the one
    its answer predicts for ``precision`` (``dc.predicted_record``)."""
    if asked == "design":
        return design_record
    if asked != "predicted":
        return float(asked)
    doc = dx.result_dict(result, trials, settings=settings, free=options["free"], targets=options["targets"])
    return dc.predicted_record(doc, design_record=design_record, precision=precision)


def at_written_record(dc, dx, result, trials, limits, settings, options, config, asked):
    """``(result at the record written, that record [s])``: the signal at the record asked
    (``written_record``), every number of the design recomputed there (``dc.at_record``)."""
    precision = config["design"]["precision"]
    record = written_record(dc, dx, result, trials, settings, options, asked, limits.record, precision)
    signal = dc.validation_signal(result, limits, record, trials=trials, key=options["key"])
    print(f"writing the design at a {record:g} s record ({asked})", flush=True)
    at = dc.at_record(
        result,
        signal,
        trials,
        free=options["free"],
        targets=targets_of(dx, options),
        precision=precision,
        draws=config["design"]["predict_draws"],
        key=options["key"],
    )
    return at, record


def main(argv=None) -> int:
    args = parse(argv)
    from armimp_jax import runtime  # after the arguments: --help stays fast

    runtime.configure()  # float64, the devices, XLA:CPU's options, the compilation cache
    import jax
    import numpy as np
    from tqdm import tqdm

    import armimp_jax as aj
    from armimp_jax.study import design_check as dc
    from armimp_jax.study import design_experiment as dx

    try:
        config = dx.read_design_config(args.config)
        trials, family, limits, options = dx.build_design(config, where=str(args.config))
        if args.sensitivity is not None:
            from armimp_jax.study.identify_recording import check_sensitivity

            check_sensitivity(trials[0], options["free"], "[design]")
    except ValueError as err:  # ConfigError included
        return fail(str(err))
    start = time.perf_counter()
    print(describe(trials, family, limits, options), flush=True)
    try:
        result = run_design(aj, trials, family, limits, options)
    except ValueError as err:
        return fail(str(err))
    if isinstance(result, aj.BoundDesign):
        trials = result.trials  # with the designed controller
    seeds = config["validate"]["seeds"] if args.validate is None else args.validate
    settings = dict(config_path=str(args.config), config=config, validate_seeds=seeds, record=args.record)
    try:  # the signal at the record asked, and every number there
        result, record = at_written_record(dc, dx, result, trials, limits, settings, options, config, args.record)
    except ValueError as err:  # the family or the limits at that length
        return fail(str(err))
    paper = paper_reference(aj, jax, result, trials, limits, options)

    def write(validation):
        doc = dx.result_dict(
            result,
            trials,
            settings=settings,
            free=options["free"],
            targets=options["targets"],
            validation=validation,
            paper=paper,
        )
        return doc, dx.write_results(args.out, result, trials, limits, doc=doc)

    # the design is written before the (long) validation, which then rewrites it: a failed or
    # interrupted check loses no design
    doc, paths = write(None)
    if seeds:
        print(f"validating at the {record:g} s record: {seeds} recordings per arm", flush=True)
        vbar = tqdm(total=seeds * len(trials), unit="fit", desc="validating")
        try:
            validation = dc.validate(
                result.signal,
                trials,
                options["free"],
                seeds=seeds,
                draws=config["validate"]["draws"],
                progress=vbar.update,
            )
        except RuntimeError as err:
            vbar.close()
            return fail(f"{err} (the design, unvalidated, is in {args.out})")
        vbar.close()
        doc, paths = write(validation)
    print_summary(np, result, doc, config, limits, on_bound=isinstance(result, aj.BoundDesign))
    if args.sensitivity is not None:
        labels = [row["label"] for row in doc["trials"]]
        lines = dx.sensitivity_report(trials, result.signal, options["free"], args.sensitivity, labels)
        print("\n".join(lines))
    print(f"{time.perf_counter() - start:.0f} s; wrote " + ", ".join(p.name for p in paths))
    return 0


if __name__ == "__main__":
    sys.exit(main())
