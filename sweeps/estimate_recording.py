"""Estimate a human arm's impedance, and fit its M, B, K, from a lab's own recording.

    python sweeps/estimate_recording.py RECORDING --fs HZ --out DIR [Welch options]

RECORDING is a CSV file (a header row, one sample per row; delimiter ',' ';' or tab;
leading '#' lines skipped; extra columns ignored) or an NPZ file, with the columns

    f_delta_x, f_delta_y   perturbation force [N] (the estimator's inputs)
    x, y                   hand (= handle) position [m]
    fh_x, fh_y             force [N] applied TO the hand by the robot handle

all sampled together at --fs [Hz]. --columns maps other names, e.g.
--columns fh_x=Fx,fh_y=Fy. An NPZ holds the six names as 1-D arrays, or f_delta, x, fh
as (N, 2) arrays ([:, 0] the x axis, [:, 1] the y axis).

Signs and frames: x, y and fh must be in one Cartesian frame (e.g. the robot base
frame); Z comes out in that frame's axes. Constant offsets do not matter (the mean is
removed per Welch segment). fh follows the arm model F_h = M xdd + B xd + K (x - x0): it
is the force the hand RECEIVES from the handle. A transducer that reads the force the
hand exerts on the handle gives -F_h: negate both fh columns, or every fitted matrix
flips sign. f_delta may be in any fixed frame, sign or scale: it cancels in Z = T R^-1.

Writes DIR/estimate.json (settings, mass [kg], damping [N s/m], stiffness [N/m] and their
standard errors as 2x2 lists indexed [force axis, displacement axis], dof and t95 for 95%
intervals, %VAF, coherence summaries), DIR/estimate.npz (f [Hz], R [m/N], T [N/N],
Z [N/m], Z_fit, coherences) and DIR/bode.png, DIR/coherence.png. Every bad input gets
one line on stderr and exit status 2, before any computation. See docs/estimation.md.
"""

from __future__ import annotations

import argparse
import math
import pathlib
import sys
import time

PROG = "estimate_recording"


def _window(text: str):
    """``hann`` -> ``"hann"``; ``tukey,0.25`` -> ``("tukey", 0.25)`` (scipy.signal.get_window)."""
    name, *params = (p.strip() for p in text.split(","))
    try:
        return (name, *map(float, params)) if params else name
    except ValueError:
        raise argparse.ArgumentTypeError(f"window parameters must be numbers, got {text!r}") from None


def parse(argv):
    ap = argparse.ArgumentParser(prog=PROG, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("recording", type=pathlib.Path, help="CSV or NPZ recording (see above)")
    ap.add_argument("--fs", type=float, required=True, metavar="HZ", help="sample rate [Hz] of the recording")
    ap.add_argument("--out", type=pathlib.Path, required=True, metavar="DIR", help="output folder (created)")
    ap.add_argument("--columns", default="", metavar="STD=NAME,...", help="map standard column names to the file's")
    ap.add_argument("--nperseg", type=int, default=8192, help="Welch segment length [samples] (default 8192)")
    ap.add_argument("--noverlap", type=int, help="Welch overlap [samples] (default 3/4 of nperseg)")
    ap.add_argument("--nfft", type=int, help="FFT length >= nperseg, zero padded (default nperseg)")
    ap.add_argument(
        "--window", type=_window, default="hann", help="scipy window name, parameters after commas (default hann)"
    )
    ap.add_argument("--fmax", type=float, default=15.0, metavar="HZ", help="highest frequency fitted [Hz] (default 15)")
    ap.add_argument(
        "--weights",
        choices=("uniform", "coherence"),
        default="uniform",
        help="least-squares weights per bin (default uniform; coherence: docs/estimation.md)",
    )
    args = ap.parse_args(argv)
    if args.noverlap is None:
        args.noverlap = 3 * args.nperseg // 4
    return args


def fail(message: str) -> int:
    print(f"{PROG}: error: {message}", file=sys.stderr)
    return 2


def main(argv=None) -> int:
    args = parse(argv)
    if not (math.isfinite(args.fs) and args.fs > 0):
        return fail(f"--fs must be a finite sample rate > 0 Hz, got {args.fs:g}")
    import jax  # after the arguments: --help stays fast

    jax.config.update("jax_enable_x64", True)
    from armimp_jax._estimation.welch import check_welch
    from armimp_jax.study import recording

    try:
        columns = recording.parse_columns(args.columns)
        rec = recording.load_recording(args.recording, columns=columns)
        n = rec["x"].shape[0]
        n_seg = check_welch(
            n,
            fs=args.fs,
            nperseg=args.nperseg,
            noverlap=args.noverlap,
            fmax=args.fmax,
            nfft=args.nfft,
            window=args.window,
        )
    except ValueError as err:  # RecordingError included
        return fail(str(err))
    start = time.perf_counter()
    welch = dict(
        fs=args.fs, nperseg=args.nperseg, noverlap=args.noverlap, nfft=args.nfft, window=args.window, fmax=args.fmax
    )
    est, fit = recording.analyse(rec, weights=args.weights, **welch)
    settings = dict(
        recording=str(args.recording),
        columns=columns,
        fs_hz=args.fs,
        nperseg=args.nperseg,
        noverlap=args.noverlap,
        nfft=args.nperseg if args.nfft is None else args.nfft,
        window=list(args.window) if isinstance(args.window, tuple) else args.window,
        fmax_hz=args.fmax,
        weights=args.weights,
    )
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
        paths = recording.write_results(args.out, est, fit, settings=settings, record=record)
    except OSError as err:
        return fail(f"cannot write to {args.out}: {err.strerror or err}")
    print(f"{n} samples, {n_seg} segments, {f.shape[0]} bins in (0, {args.fmax:g}] Hz; VAF {fit.vaf_overall:.1f} %")
    for name, unit in (("mass", "kg"), ("damping", "N s/m"), ("stiffness", "N/m")):
        value, se = getattr(fit, name), getattr(fit, f"{name}_se")
        rows = ["  ".join(f"{value[i, j]:10.4g} +- {se[i, j]:<8.2g}" for j in range(2)) for i in range(2)]
        print(f"{name} [{unit}]:\n  " + "\n  ".join(rows))
    print(f"wrote {', '.join(str(p) for p in paths)} in {time.perf_counter() - start:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
