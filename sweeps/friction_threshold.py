"""The friction threshold: how much Coulomb friction a robot may have before it spoils the estimate.

    python sweeps/friction_threshold.py --quick                # 12 s records, 2 seeds, 10 friction points
    python sweeps/friction_threshold.py                        # 50 s records, 5 seeds, 16 friction points
    python sweeps/friction_threshold.py --seeds 10 --out DIR

phi_T and the minimum multiple coherence against the Coulomb torque tau_c from 0 to 4 N m
(0, log-spaced points from 1e-3 to 4 N m, plus 0.05 and 1 N m; stiction 1.5 tau_c, the
paper's bristle and viscous parameters), PD and IMBIC (Mhat = 0.25 I kg), the four paper
arms, perturbation level 1, seeds with common random numbers, SWEEP_NUMERICS (ARK3, 20
substeps). Writes DIR/report.md and DIR/friction_threshold.png besides the sweep's own
files (docs/sweeps.md); a second call with the same options reuses the finished trials.
"""

from __future__ import annotations

import pathlib
import sys
import time

from armimp_jax.study.runs.cli import METHODS, Parser, fail, script

PROG = "friction_threshold"
FULL = dict(seconds=50.0, nperseg=8192, seeds=5, points=13)
QUICK = dict(seconds=12.0, nperseg=2048, seeds=2, points=7)


def parse(argv):
    ap = Parser(prog=PROG, description=__doc__)
    ap.add_argument("--quick", action="store_true", help="12 s records, 2048-sample segments, 2 seeds, 7+3 points")
    ap.add_argument("--seeds", type=int, help="seeds per point (default 5; quick 2)")
    ap.add_argument("--seconds", type=float, help="record length [s] (default 50; quick 12)")
    ap.add_argument("--nperseg", type=int, help="Welch segment [samples] (default 8192; quick 2048), overlap 3/4")
    ap.add_argument("--points", type=int, help="log-spaced tau_c points in [1e-3, 4] N m (default 13; quick 7)")
    ap.add_argument("--method", choices=METHODS, help="integrator (default ark3)")
    ap.add_argument("--substeps", type=int, help="integration steps per 1 ms (default 20)")
    ap.add_argument("--check", type=int, default=0, metavar="N", help="re-run N trials per controller at 4x substeps")
    ap.add_argument("--batch-size", type=int, default=64, help="trials per vmapped batch (does not change results)")
    ap.add_argument("--out", type=pathlib.Path, help="output folder (default results/friction-threshold[-quick])")
    args = ap.parse_args(argv)
    base = QUICK if args.quick else FULL
    for name, default in base.items():
        if getattr(args, name) is None:
            setattr(args, name, default)
    for name in ("seeds", "points", "batch_size"):
        if getattr(args, name) < 1:
            fail(f"--{name.replace('_', '-')} must be >= 1, got {getattr(args, name)}", PROG)
    if args.points < 2:
        fail(f"--points must be >= 2 (log spacing), got {args.points}", PROG)
    if args.substeps is not None and args.substeps < 1:
        fail(f"--substeps must be >= 1, got {args.substeps}", PROG)
    if args.check < 0:
        fail(f"--check must be >= 0, got {args.check}", PROG)
    if args.out is None:
        args.out = pathlib.Path("results/friction-threshold-quick" if args.quick else "results/friction-threshold")
    return args


@script(PROG)
def main(argv=None) -> int:
    args = parse(argv)
    from armimp_jax.runtime import configure

    configure()
    from armimp_jax.study.runs.console import Console
    from armimp_jax.study.sweep import sweep, threshold

    settings = threshold.threshold_settings(
        seconds=args.seconds,
        nperseg=args.nperseg,
        seeds=args.seeds,
        points=args.points,
        method=args.method,
        substeps=args.substeps,
    )
    console = Console()
    start = time.perf_counter()
    result, path = threshold.run_threshold(
        settings, args.out, batch_size=args.batch_size, check=args.check, console=console, warn=console.warn(PROG)
    )
    print("\n".join(sweep.summary_lines(result, args.out, time.perf_counter() - start)))
    print(f"report: {path}")
    return 0 if result["complete"] else 1


if __name__ == "__main__":
    sys.exit(main())
