"""Estimate a human arm's impedance, and fit its M, B, K with 95% intervals, from a lab's own recording.

    python sweeps/estimate_recording.py RECORDING --fs HZ --out DIR [Welch and fit options]
    python sweeps/estimate_recording.py RECORDING --fs 1000 --model CONFIG.toml --out DIR
    python sweeps/estimate_recording.py --fs 1000 --model POOL.toml --out DIR

RECORDING is a CSV file (a header row, one sample per row; delimiter ',' ';' or tab;
leading '#' lines skipped; extra columns ignored), an NPZ file or a MATLAB MAT-file (v7 or
older: save(file, ..., '-v7')), with the columns

    f_delta_x, f_delta_y   perturbation force [N] (the estimator's inputs)
    x, y                   hand (= handle) position [m]
    fh_x, fh_y             force [N] applied TO the hand by the robot handle

all sampled together at --fs [Hz]. --columns maps other names, e.g.
--columns fh_x=Fx,fh_y=Fy. An NPZ or MAT-file holds the six names as vectors, or f_delta,
x, fh as (N, 2) arrays ([:, 0] the x axis, [:, 1] the y axis).

Signs and frames: x, y and fh must be in one Cartesian frame (e.g. the robot base
frame); Z comes out in that frame's axes. Constant offsets do not matter (the mean is
removed per Welch segment). fh follows the arm model F_h = M xdd + B xd + K (x - x0): it
is the force the hand RECEIVES from the handle. A transducer that reads the force the
hand exerts on the handle gives -F_h: negate both fh columns, or every fitted matrix
flips sign. f_delta may be in any fixed frame, sign or scale: it cancels in Z = T R^-1.

Timing (--acquisition): how force and position were sampled decides the model fitted to
Z. 'delay' (default, for a recording whose timing is unknown) fits a force-channel delay
with M, B, K; 'instant' (samples at the control instants, force read just before the
command's zero-order-hold update, as the simulator does by default), 'interval_mean'
(box-car means over each sample period) and 'plain' (M s^2 + B s + K as it stands, no
model of the sampling) are the others. Instant or delayed force samples through a robot
with joint friction bias M and B in a way the fit cannot show: give --friction, your
robot's friction torque, and a warning says so when it is above 0; not given, the warning
fires when the record shows stick-slip (the force's broadband excess), and the report's
first line says so. Standard errors (--se) come
from the Welch estimate's own error model ('spectral', default) or from the fit's
residuals ('residual', too small: the Welch bins are correlated). Welch segments follow
the record's length unless --nperseg is given (armimp_jax.spectra.welch_segments).

Prints the 95% intervals of M, B, K (and the delay), the VAF and the lack-of-fit test
with one verdict on both (a passing test on a noisy estimate: no evidence against the
model at that noise, and the low VAF is the noise), the coherence summary and every
warning. Writes DIR/estimate.json (settings, values, standard errors,
dof, 95% intervals, delay, lack of fit, %VAF, coherence summaries, warnings),
DIR/estimate.npz (f [Hz], R [m/N], T [N/N], Z [N/m], Z_fit, coherences, the error model)
and DIR/bode.png, DIR/coherence.png. Every bad input gets one line on stderr and exit
status 2, before any computation. See docs/estimation.md.

The model route (--model CONFIG.toml) fits the arm's M, B, K (and the robot's friction)
through the friction-aware closed-loop simulation instead (armimp_jax.identify), with the
robot, controller, acquisition, noise model, starting values and free parameters of the
TOML file (keys, units and defaults: docs/identify_recording.md). The recording must then
be sampled at the simulator's control rate (1000 Hz), f_delta must be the force [N] added
to the robot's command in the frame of x and fh, and x must be in the model's world frame
(origin at the shoulder, as the config's arm endpoint). The Welch and fit options above do
not apply. Prints convergence, each parameter as value +- SE (the arm's beside the
classical answer: the Welch route at its defaults on the same recording) and where the
fit cannot be trusted; writes DIR/identification.json, DIR/identification.csv, DIR/position.png,
DIR/residual_spectrum.png, DIR/frf.png and DIR/stiffness_ellipse.png.

Several recordings (postures, repeated trials, the robot alone) in one identification: a
--model config with a [recordings] section (files, one group per file, the groups recorded
alone, the shared names) and no RECORDING; each recording's model rests at its first hand
position. Writes one table: the arm per group, the robot shared (docs/identify_recording.md).
"""

from __future__ import annotations

import argparse
import math
import pathlib
import sys
import time

from armimp_jax.study.runs.cli import Parser, error_line, import_kinds

PROG = "estimate_recording"
# the Welch route's options (estimate_recording.ROUTE_DEFAULTS, then --friction); the model route takes none
WELCH_OPTIONS = ("nperseg", "noverlap", "nfft", "window", "fmax", "weights", "acquisition", "period", "se", "friction")


def _window(text: str):
    """``hann`` -> ``"hann"``; ``tukey,0.25`` -> ``("tukey", 0.25)`` (scipy.signal.get_window)."""
    name, *params = (p.strip() for p in text.split(","))
    try:
        return (name, *map(float, params)) if params else name
    except ValueError:
        raise argparse.ArgumentTypeError(f"window parameters must be numbers, got {text!r}") from None


def parse(argv):
    ap = Parser(prog=PROG, description=__doc__, kinds=True)
    ap.add_argument(
        "recording",
        type=pathlib.Path,
        nargs="?",
        help="CSV, NPZ or MAT recording (see above); none with a --model config that lists its [recordings]",
    )
    ap.add_argument("--fs", type=float, required=True, metavar="HZ", help="sample rate [Hz] of the recording")
    ap.add_argument("--out", type=pathlib.Path, required=True, metavar="DIR", help="output folder (created)")
    ap.add_argument("--columns", default="", metavar="STD=NAME,...", help="map standard column names to the file's")
    ap.add_argument(
        "--model",
        type=pathlib.Path,
        metavar="CONFIG.toml",
        help="the model route: identify through the closed-loop simulation with this config "
        "(docs/identify_recording.md); the Welch and fit options below do not apply",
    )
    ap.add_argument(
        "--nperseg",
        type=int,
        help="Welch segment length [samples] (default: follows the record's length, armimp_jax.spectra.welch_segments; "
        "Table 4's 8192 on a long record)",
    )
    ap.add_argument("--noverlap", type=int, help="Welch overlap [samples] (default 3/4 of nperseg)")
    ap.add_argument("--nfft", type=int, help="FFT length >= nperseg, zero padded (default nperseg)")
    ap.add_argument("--window", type=_window, help="scipy window name, parameters after commas (default hann)")
    ap.add_argument("--fmax", type=float, metavar="HZ", help="highest frequency fitted [Hz] (default 15)")
    choices = (  # option, its choices (the first is the default), help
        ("weights", ("uniform", "coherence"), "least-squares weights per bin (coherence: docs/estimation.md)"),
        (
            "acquisition",
            ("delay", "instant", "interval_mean", "plain"),
            "how the record was sampled: the model fitted to Z (delay: timing unknown, see above)",
        ),
        ("se", ("spectral", "residual"), "standard errors from the estimate's error model or the fit's residuals"),
    )
    for name, allowed, text in choices:
        ap.add_argument(f"--{name}", choices=allowed, help=f"{text} (default {allowed[0]})")
    ap.add_argument("--period", type=float, metavar="S", help="hold period [s] of --acquisition instant (default 1/fs)")
    ap.add_argument(
        "--lines",
        action="store_true",
        help="fit only the bins that hold the perturbation on both axes (a multisine's lines, e.g. a designed one)",
    )
    ap.add_argument(
        "--friction",
        type=float,
        metavar="N_M",
        help="your robot's largest joint Coulomb friction torque [N m] (default: unknown, read from the record's "
        "stick-slip, as the report says); with instant or delay timing a robot with friction biases M and B in "
        "ways the fit cannot show, and a warning says so",
    )
    ap.add_argument(
        "--sensitivity",
        type=float,
        metavar="PERCENT",
        help="the model route: also print how far a PERCENT error in each robot parameter (link inertias, "
        "friction, force gain; 1 ms of force delay) would move each arm entry, in SEs "
        "(armimp_jax.experiment.robot_sensitivity; a binding more)",
    )
    args = ap.parse_args(argv)
    if args.sensitivity is not None and (args.model is None or not 0 < args.sensitivity <= 100):
        ap.error(f"--sensitivity takes a percentage in (0, 100] with --model, got {args.sensitivity}")
    given = [f"--{k}" for k in WELCH_OPTIONS if getattr(args, k) is not None]
    given += ["--lines"] if args.lines else []
    if args.model is not None and given:
        ap.error(f"--model takes its settings from the config; not with the Welch route's {', '.join(given)}")
    if args.model is None and args.recording is None:
        ap.error("the Welch route needs a RECORDING")
    if args.friction is not None and not args.friction >= 0:
        ap.error(f"--friction must be >= 0 N m, got {args.friction}")
    return args


def fail(message: str) -> int:
    return error_line(message, PROG)


def start_jax(args) -> None:
    """The set-up (float64, the devices, XLA:CPU's options, the compilation cache) and the lab's
    own kinds (--import), after the arguments (--help stays fast)."""
    from armimp_jax import runtime

    runtime.configure()
    import_kinds(args.imports, PROG)


def load(args, recording) -> tuple[dict, dict]:
    """``(columns, recording)`` of the command line; a missing column's message names --columns."""
    columns = recording.parse_columns(args.columns)
    try:
        return columns, recording.load_recording(args.recording, columns=columns)
    except recording.MissingColumnsError as err:
        raise ValueError(err.for_option("--columns")) from None


def main(argv=None) -> int:
    args = parse(argv)
    if not (math.isfinite(args.fs) and args.fs > 0):
        return fail(f"--fs must be a finite sample rate > 0 Hz, got {args.fs:g}")
    if args.model is not None:
        return model_route(args)
    if args.period is not None and not (math.isfinite(args.period) and args.period > 0):
        return fail(f"--period must be a finite hold period > 0 s, got {args.period:g}")
    start_jax(args)
    import armimp_jax as aj
    from armimp_jax.study.recording import estimate_recording, recording, recording_report

    options = {k: getattr(args, k) for k in WELCH_OPTIONS if k != "friction" and getattr(args, k) is not None}
    try:
        columns, rec = load(args, recording)
        n = rec["x"].shape[0]
        welch, fit_settings, n_seg = estimate_recording.route_settings(n, fs=args.fs, **options)
    except ValueError as err:  # RecordingError included
        return fail(str(err))
    start = time.perf_counter()
    _, share = estimate_recording.input_bins(rec["f_delta"], welch)
    try:
        est, fit = estimate_recording.analyse(rec, **welch, **fit_settings, lines=args.lines)
    except ValueError as err:
        return fail(str(err))
    acquisition = fit_settings["acquisition"]
    # friction not given: unknown, so the record's stick-slip decides (the report's first line says so)
    warnings = recording.timestamp_warnings(rec, args.fs)  # the file's own clock against --fs
    warnings += aj.spectra.fit_warnings(fit, est, acquisition=acquisition, friction=args.friction)
    settings = dict(
        recording=str(args.recording), columns=columns, **estimate_recording.settings_record(welch, fit_settings)
    )
    settings["friction_n_m"] = args.friction
    settings["lines"] = args.lines
    f = est.f
    record = dict(
        n_samples=n,
        duration_s=n / args.fs,
        n_segments=n_seg,
        n_bins=int(f.shape[0]),
        f_min_hz=f[0],
        f_max_hz=f[-1],
        resolution_hz=args.fs / settings["nfft"],
    )
    try:
        paths = estimate_recording.write_results(
            args.out, est, fit, settings=settings, record=record, warnings=warnings, share=share, lines=args.lines
        )
    except OSError as err:
        return fail(f"cannot write to {args.out}: {err.strerror or err}")
    print(f"{n} samples, {n_seg} segments, {f.shape[0]} bins in (0, {welch['fmax']:g}] Hz")
    report = recording_report.welch_report(
        est,
        fit,
        acquisition=acquisition,
        warnings=warnings,
        friction_given=args.friction is not None,
        share=share,
        lines=args.lines,
    )
    print("\n".join(report))
    print(f"wrote {', '.join(str(p) for p in paths)} in {time.perf_counter() - start:.1f} s")
    return 0


def model_route(args) -> int:
    """Identify through the closed-loop model (armimp_jax.study.recording.identify_recording), with the
    Welch route's answer at its defaults beside it (the classical column)."""
    start_jax(args)
    from armimp_jax.study.recording import calibration_files as cf
    from armimp_jax.study.recording import identify_recording as idr
    from armimp_jax.study.recording import recording, recording_report

    try:  # every check before the fit: the config, the rate, the recording, the calibration
        config = idr.read_identify_config(args.model)
        model, options = idr.build_model(config, where=str(args.model))
        idr.check_rate(args.fs, model)
        if "recordings" in config:
            if args.recording is not None:
                raise ValueError(f"{args.model} lists its recordings in [recordings]: give no RECORDING")
            if args.sensitivity is not None:
                raise ValueError("--sensitivity takes one RECORDING, not a [recordings] list (not yet)")
            return pooled_route(args, config, options)
        if args.recording is None:
            raise ValueError(f"{args.model} has no [recordings]: give the RECORDING to identify")
        if args.sensitivity is not None:
            idr.check_sensitivity(model, options["free"])
        columns, rec = load(args, recording)
        options["calibration"], lines = cf.calibrate(config, args.model, args.fs, columns, model.robot)
    except ValueError as err:  # IdentifyConfigError and RecordingError included
        return fail(str(err))
    n, clock = rec["x"].shape[0], recording.timestamp_warnings(rec, args.fs)
    start = f"{n} samples ({n / args.fs:g} s); identifying {', '.join(options['free'])} ..."
    print("\n".join(lines + [f"WARNING: {w}" for w in clock] + [start]), flush=True)
    try:
        res = idr.run(rec, model, options)
    except ValueError as err:  # identify's own refusals (e.g. a start at which the model diverges)
        return fail(str(err))
    classical = idr.classical_fit(rec, args.fs)
    warnings = clock + idr.trust_warnings(res, rec, classical)
    settings = dict(
        recording=str(args.recording), columns=columns, fs_hz=args.fs, config_path=str(args.model), config=config
    )
    settings["calibration"] = cf.record(options["calibration"])
    try:
        paths = idr.write_results(
            args.out,
            res,
            rec,
            model=model,
            settings=settings,
            numerics=options["numerics"],
            warnings=warnings,
            classical=classical,
        )
    except OSError as err:
        return fail(f"cannot write to {args.out}: {err.strerror or err}")
    print("\n".join(recording_report.model_report(res, None if classical is None else classical[1], warnings)))
    print(f"wrote {', '.join(str(p) for p in paths)}")
    if args.sensitivity is not None:
        try:
            print("\n".join(idr.sensitivity_report(res, rec, options, args.sensitivity)))
        except ValueError as err:
            return fail(str(err))
    return 0


def pooled_route(args, config: dict, options: dict) -> int:
    """Every recording of the config's [recordings] in one identification (study.recording.identify_pool):
    one table of the arm per group and the shared robot."""
    import armimp_jax as aj
    from armimp_jax.study.recording import calibration_files as cf
    from armimp_jax.study.recording import identify_pool, recording, recording_report
    from armimp_jax.study.recording import identify_recording as idr

    try:
        columns = recording.parse_columns(args.columns)
        listed = identify_pool.files(config, args.model)
        loaded = [(g, recording.load_recording(path, columns=columns)) for path, g in listed]
        recordings = identify_pool.build_recordings(config, loaded, str(args.model))
        robot = recordings[0].model.robot
        options["calibration"], lines = cf.calibrate(config, args.model, args.fs, columns, robot)
    except ValueError as err:  # ConfigError and RecordingError included
        return fail(str(err))
    names = [p.name for p, _ in listed]
    clock = [
        f"recording {n}: {w}" for n, (_, r) in zip(names, loaded) for w in recording.timestamp_warnings(r, args.fs)
    ]
    start = f"{len(recordings)} recordings in {len(set(g for _, g in listed))} groups; identifying ..."
    print("\n".join(lines + [f"WARNING: {w}" for w in clock] + [start]), flush=True)
    try:
        res = aj.identify(recordings, **options, shared=config["recordings"]["shared"], progress=True)
    except ValueError as err:
        return fail(str(err))
    classical = [idr.classical_fit(rec, args.fs) for _, rec in loaded]
    warnings = clock + idr.pooled_warnings(res, names, loaded, classical)
    settings = dict(recordings=[str(p) for p, _ in listed], columns=columns, fs_hz=args.fs, config_path=str(args.model))
    settings["config"], settings["calibration"] = config, cf.record(options["calibration"])
    try:
        paths = identify_pool.write_results(args.out, res, settings=settings, warnings=warnings, classical=classical)
    except OSError as err:
        return fail(f"cannot write to {args.out}: {err.strerror or err}")
    print("\n".join(recording_report.pooled_report(res, names, classical, warnings)))
    print(f"wrote {', '.join(str(p) for p in paths)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
