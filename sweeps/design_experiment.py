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

import pathlib
import sys
import time

from armimp_jax.study.runs.cli import Parser, error_line, import_kinds

PROG = "design_experiment"


def parse(argv):
    ap = Parser(prog=PROG, description=__doc__, kinds=True)
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
        "force delay) would move each arm entry, in SEs (armimp_jax.experiment.robot_sensitivity per arm)",
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


def main(argv=None) -> int:
    args = parse(argv)
    from armimp_jax import runtime  # after the arguments: --help stays fast

    runtime.configure()  # float64, the devices, XLA:CPU's options, the compilation cache
    import_kinds(args.imports, PROG)
    from tqdm import tqdm

    import armimp_jax as aj
    from armimp_jax.study.design import design_check as dc
    from armimp_jax.study.design import design_experiment as dx
    from armimp_jax.study.design import design_report as dr

    try:
        config = dx.read_design_config(args.config)
        trials, family, limits, options = dx.build_design(config, where=str(args.config))
        if args.sensitivity is not None:
            from armimp_jax.study.recording.identify_recording import check_sensitivity

            check_sensitivity(trials[0], options["free"], "[design]")
    except ValueError as err:  # ConfigError included
        return fail(str(err))
    start = time.perf_counter()
    print(dr.describe(trials, family, limits, options), flush=True)
    try:
        result = dr.run_design(trials, family, limits, options)
    except ValueError as err:
        return fail(str(err))
    if isinstance(result, aj.results.BoundDesign):
        trials = result.trials  # with the designed controller
    seeds = config["validate"]["seeds"] if args.validate is None else args.validate
    settings = dict(config_path=str(args.config), config=config, validate_seeds=seeds, record=args.record)
    try:  # the signal at the record asked, and every number there
        result, record = dr.at_written_record(result, trials, limits, settings, options, config, args.record)
    except ValueError as err:  # the family or the limits at that length
        return fail(str(err))
    paper = dr.paper_reference(result, trials, limits, options)

    def write(validation):
        free, targets = options["free"], options["targets"]
        doc = dx.result_dict(
            result, trials, settings=settings, free=free, targets=targets, validation=validation, paper=paper
        )
        return doc, dx.write_results(args.out, result, trials, limits, doc=doc)

    # the design is written before the (long) validation, which then rewrites it: a failed or
    # interrupted check loses no design
    doc, paths = write(None)
    if seeds:
        print(f"validating at the {record:g} s record: {seeds} recordings per arm", flush=True)
        with tqdm(total=seeds * len(trials), unit="fit", desc="validating") as vbar:
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
                return fail(f"{err} (the design, unvalidated, is in {args.out})")
        doc, paths = write(validation)
    print(
        "\n".join(
            [
                *dr.summary_lines(result, doc, config, limits),
                dr.robot_alone_line(trials, result.signal, options["free"]),
            ]
        )
    )
    if args.sensitivity is not None:
        labels = [row["label"] for row in doc["trials"]]
        print("\n".join(dx.sensitivity_report(trials, result.signal, options["free"], args.sensitivity, labels)))
    print(f"{time.perf_counter() - start:.0f} s; wrote " + ", ".join(p.name for p in paths))
    return 0


if __name__ == "__main__":
    sys.exit(main())
