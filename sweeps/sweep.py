"""Sweep any settings of a trial over a grid (or a list of points) times seeds.

    python sweeps/sweep.py --set controller=pd,imbic --set tau_c=0,0.1,1 --seeds 5 --out results/my-sweep
    python sweeps/sweep.py --set tau_c=geom:0.001:4:13 --set arm=1,2,3,4 --seconds 20 --out DIR
    python sweeps/sweep.py --config sweep.toml --out DIR     # [friction], [record] ..., [[points]], [run]
    python sweeps/sweep.py --resume DIR                      # finish an interrupted sweep

Settings (``--set NAME=V1,...`` or ``--set section.key=V1,...``, or a trial's sections in TOML; docs/sweeps.md):
controller, tau_c [N m], stiction_ratio, sigma0, sigma1, sigma2, v_s, arm (1-4 or a user
arm in TOML), perturbation_level or peak [N], seconds, force_noise [N], encoder_counts,
velocity_noise [rad/s], acquisition, mhat [kg], nperseg, noverlap, fmax [Hz], window, nfft.

Writes DIR/trials.csv (one row per trial), DIR/summary.csv and summary.json (per point
over seeds: mean, sd, 95% CI, diverged count), the two tables as .parquet too when pyarrow
is installed, DIR/<swept>.png, DIR/run.json and one checked record per trial under
DIR/trials (from Python: armimp_jax.study.load_sweep(DIR), load_summary(DIR)). A folder
holds one sweep: the same command reuses its finished trials; other settings are refused
(docs/results.md).
"""

from __future__ import annotations

import pathlib
import sys
import time

from armimp_jax.study.runs.cli import METHODS, Parser, distributed_options, fail, import_kinds, script

PROG = "sweep"
SHORTCUTS = ("seconds", "nperseg", "noverlap", "mhat")  # options that set one value of a point setting
RUN_OPTIONS = ("seeds", "base_seed", "method", "substeps")


def parse(argv):
    ap = Parser(prog=PROG, description=__doc__, kinds=True)
    ap.add_argument("--set", action="append", default=[], metavar="NAME=V1,V2", help="sweep (or fix) a setting")
    ap.add_argument("--config", type=pathlib.Path, metavar="TOML", help="settings and points from a TOML file")
    ap.add_argument("--seconds", type=float, help="record length [s] (default 50)")
    ap.add_argument("--nperseg", type=int, help="Welch segment [samples] (default 8192)")
    ap.add_argument("--noverlap", type=int, help="Welch overlap [samples] (default 3/4 nperseg)")
    ap.add_argument("--mhat", type=float, help="IMBIC Mhat, times the identity [kg] (default 0.25)")
    ap.add_argument("--seeds", type=int, help="perturbation seeds per point (default 3)")
    ap.add_argument("--base-seed", type=int, help="PRNG seed the perturbations are folded from (default 0)")
    ap.add_argument("--method", choices=METHODS, help="integrator (default ark3)")
    ap.add_argument("--substeps", type=int, help="integration steps per 1 ms period (default 20)")
    ap.add_argument("--check", type=int, default=0, metavar="N", help="re-run N trials per group at 4x substeps")
    ap.add_argument("--batch-size", type=int, default=64, help="trials per vmapped batch (does not change results)")
    ap.add_argument("--x", metavar="NAME", help="setting on the figure's x axis (default: the first swept number)")
    ap.add_argument("--out", type=pathlib.Path, help="output folder")
    ap.add_argument("--resume", type=pathlib.Path, metavar="DIR", help="finish the sweep in DIR with its own settings")
    distributed_options().add_arguments(ap)
    args = ap.parse_args(argv)
    if (args.out is None) == (args.resume is None):
        fail("give one of --out DIR and --resume DIR", PROG)
    if args.resume is not None and not args.resume.is_dir():
        fail(f"--resume {args.resume}: no such folder", PROG)
    for name, least in (("batch_size", 1), ("seeds", 1), ("substeps", 1), ("check", 0), ("base_seed", 0)):
        v = getattr(args, name)
        if v is not None and v < least:
            fail(f"--{name.replace('_', '-')} must be >= {least}, got {v}", PROG)
    try:
        distributed_options().check_arguments(args)
    except ValueError as err:
        fail(str(err), PROG)
    return args


@script(PROG)
def main(argv=None) -> int:
    args = parse(argv)
    distributed = distributed_options()
    distributed.initialize(args)  # before the backend starts (configure starts it)
    from armimp_jax.runtime import configure

    configure()
    import_kinds(args.imports, PROG)
    from armimp_jax.study.runs.console import Console
    from armimp_jax.study.sweep import sweep

    given = dict(
        config=args.config,
        sets=args.set,
        shortcuts={k: getattr(args, k) for k in SHORTCUTS if getattr(args, k) is not None},
        run={k: getattr(args, k) for k in RUN_OPTIONS if getattr(args, k) is not None},
    )
    out = args.out or args.resume
    settings = sweep.requested(**given) if args.resume is None else sweep.resumed(args.resume, **given)
    console = Console()
    start = time.perf_counter()
    result = sweep.run_sweep(
        settings, out, batch_size=args.batch_size, check=args.check, x=args.x, console=console, warn=console.warn(PROG)
    )
    if not distributed.is_writer():
        import jax

        print(f"{PROG}: process {jax.process_index()} done; process 0 wrote the results")
        return 0
    print("\n".join(sweep.summary_lines(result, out, time.perf_counter() - start)))
    return 0 if result["complete"] else 1


if __name__ == "__main__":
    sys.exit(main())
