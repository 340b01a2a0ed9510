"""Design the perturbation of an impedance experiment within a patient's limits, and check it.

    python sweeps/design_experiment.py CONFIG.toml --out DIR [--validate SEEDS [--validate-record predicted]]

CONFIG.toml names the robot, controller, sensors, the person's own force and the friction
(as the model route of estimate_recording.py), the arm to design for ([arm], or the
paper's arm locations in [design] robust), the perturbation family ([family]: shaped
noise or a multisine over a band), the limits ([limits]: RMS and peak force per axis [N],
peak hand displacement [m], record length [s]) and what to minimise ([design]: the free
parameters, the target entries, the criterion). Keys, units and defaults:
docs/experiment_design.md; an example: sweeps/configs/design_example.toml.

Writes DIR/perturbation.csv (f_delta_x, f_delta_y [N], one row per 1 ms: what the robot's
software loads), DIR/perturbation.npz, DIR/design.json (settings, limits met, predicted SEs
before and after, the optimisation trace, the check) and DIR/spectrum.png, DIR/se.png,
DIR/trace.png. With --validate SEEDS (or [validate] seeds) it simulates and identifies
SEEDS recordings per arm under new noise with the designed perturbation and reports the
spread of the estimates against the predicted SEs; --validate-record predicted (or
[validate] record) runs it at the record the design's minutes predict (the family's signal at
that length, within the same limits, written as DIR/perturbation_checked.csv), where the
spread should meet the precision asked. A bound's minutes leave the joints' friction out:
calibrate ([design] calibrate) before trusting them through friction. Every bad config gets one line on
stderr and exit status 2, before any computation.
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
    ap.add_argument("--validate", type=int, metavar="SEEDS", help="Monte Carlo check: recordings per arm")
    ap.add_argument(
        "--validate-record",
        metavar="{design,predicted}",
        help="the check's record: the design's (default) or the one its minutes predict",
    )
    args = ap.parse_args(argv)
    if args.validate is not None and args.validate < 0:
        ap.error(f"--validate must be >= 0 recordings, got {args.validate}")
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
        p = config["design"]["precision"]
        print(f"controller: {result.controller}")
        print(
            f"minutes for +-{p:.0%} at 95% on every target, per arm: start "
            f"{np.round(result.start_minutes, 2).tolist()}, designed {np.round(result.minutes, 2).tolist()}; "
            f"drift {1e3 * result.achieved['drift']:.3f} mm"
        )
        from armimp_jax.study.design_experiment import friction_note

        note = friction_note(result)
        if note:
            print(note)
    worst_paper = max(max(row["relative_se_paper"].values()) for row in doc["trials"])
    print(f"the paper's perturbation at the same peak: {worst_paper:.4g}")
    print(
        f"limits met: RMS {np.round(result.achieved['rms_force'], 4).tolist()} N, peak "
        f"{np.round(result.achieved['peak_force'], 4).tolist()} N, displacement "
        f"{1e3 * result.achieved['peak_displacement']:.3f} mm"
    )
    if "validation" in doc:
        v, p = doc["validation"], config["design"]["precision"]
        print(
            f"checked at a {v['record_s']:g} s record: RMS {np.round(v['rms_force'], 4).tolist()} N, peak "
            f"{np.round(v['peak_force'], 4).tolist()} N; the predictions scaled to it (asked: +-{p:.0%} at 95%)"
        )
    for k, row in enumerate(doc["trials"]):
        if "validation" in row:
            check = row["validation"]
            spread, predicted = check["relative_spread"], check["relative_se_predicted"]
            worst = max(spread, key=spread.get)
            print(
                f"arm {k + 1}: largest relative spread {spread[worst]:.4g} ({worst}) / largest predicted "
                f"{max(predicted.values()):.4g} = {spread[worst] / max(predicted.values()):.2f}; +-"
                f"{Z95 * spread[worst]:.1%} at 95% ({check['converged']} of {check['recordings']} recordings "
                "converged)"
            )


def check_options(args, config, records) -> tuple[int, str]:
    """The check's recordings per arm and its record (the command line over the config); a
    ``ValueError`` for an unknown record, or a record given on the command line for no check."""
    seeds = config["validate"]["seeds"] if args.validate is None else args.validate
    at = config["validate"]["record"] if args.validate_record is None else args.validate_record
    if at not in records:
        raise ValueError(f"--validate-record must be one of {', '.join(map(repr, records))}, got {at!r}")
    if args.validate_record is not None and not seeds:
        raise ValueError(f"--validate-record {at} sets the check's record, but no check runs: add --validate SEEDS")
    return seeds, at


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
        seeds, at = check_options(args, config, dx.VALIDATE_RECORDS)
    except ValueError as err:  # ConfigError included
        return fail(str(err))
    start = time.perf_counter()
    print(describe(trials, family, limits, options), flush=True)
    try:
        result = run_design(aj, trials, family, limits, options)
    except ValueError as err:
        return fail(str(err))
    paper = paper_reference(aj, jax, result, trials, limits, options)
    if isinstance(result, aj.BoundDesign):
        trials = result.trials  # with the designed controller
    settings = dict(config_path=str(args.config), config=config, validate_seeds=seeds, validate_record=at)

    def write(validation, checked=None):
        doc = dx.result_dict(
            result,
            trials,
            settings=settings,
            free=options["free"],
            targets=options["targets"],
            validation=validation,
            paper=paper,
            validation_signal=checked,
        )
        return doc, dx.write_results(args.out, result, trials, limits, doc=doc, checked=checked)

    # the design is written before the (long) validation, which then rewrites it: a failed or
    # interrupted check loses no design
    doc, paths = write(None)
    if seeds:
        precision = config["design"]["precision"]
        predicted = at == "predicted"
        record = (
            dc.predicted_record(doc, design_record=limits.record, precision=precision) if predicted else limits.record
        )
        print(f"validating at a {record:g} s record ({at}): {seeds} recordings per arm", flush=True)
        try:
            signal = dc.validation_signal(result, limits, record, trials=trials, key=options["key"])
        except ValueError as err:  # the family or the limits at that length
            return fail(f"{err} (the design, unvalidated, is in {args.out})")
        vbar = tqdm(total=seeds * len(trials), unit="fit", desc="validating")
        try:
            validation = dc.validate(
                signal,
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
        doc, paths = write(validation, signal)
    print_summary(np, result, doc, config, limits, on_bound=isinstance(result, aj.BoundDesign))
    print(f"{time.perf_counter() - start:.0f} s; wrote " + ", ".join(p.name for p in paths))
    return 0


if __name__ == "__main__":
    sys.exit(main())
