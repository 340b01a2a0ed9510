"""Sweep any settings of a trial over a grid (or a list of points) times seeds.

    python sweeps/sweep.py --set controller=pd,imbic --set tau_c=0,0.1,1 --seeds 5 --out results/my-sweep
    python sweeps/sweep.py --set tau_c=geom:0.001:4:13 --set arm=1,2,3,4 --seconds 20 --out DIR
    python sweeps/sweep.py --config grid.toml --out DIR      # [grid], [[points]], [run] tables
    python sweeps/sweep.py --resume DIR                      # finish an interrupted sweep

Settings (``--set NAME=V1,V2,...``, or ``[grid]``/``[[points]]`` in TOML; see docs/sweeps.md):
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

import argparse
import dataclasses
import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from _cli import METHODS, Parser, distributed_options, run_sweep  # noqa: E402
from _cli import fail as cli_fail  # noqa: E402

PROG = "sweep"
SHORTCUTS = ("seconds", "nperseg", "noverlap", "mhat")  # options that set one value of a point setting


def fail(message: str, prog: str = PROG):
    cli_fail(message, prog)


def parser(prog: str = PROG, description: str | None = __doc__) -> Parser:
    ap = Parser(prog=prog, description=description, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--set", action="append", default=[], metavar="NAME=V1,V2", help="sweep (or fix) a setting")
    ap.add_argument("--config", type=pathlib.Path, metavar="TOML", help="grid and points from a TOML file")
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
    return ap


def check_args(args, prog: str = PROG) -> None:
    """Checks that need no simulation (before JAX is imported)."""
    if (args.out is None) == (args.resume is None):
        fail("give one of --out DIR and --resume DIR", prog)
    if args.resume is not None and not args.resume.is_dir():
        fail(f"--resume {args.resume}: no such folder", prog)
    for name in ("batch_size", "seeds", "substeps"):
        v = getattr(args, name, None)
        if v is not None and v < 1:
            fail(f"--{name.replace('_', '-')} must be >= 1, got {v}", prog)
    if args.check < 0:
        fail(f"--check must be >= 0, got {args.check}", prog)
    if args.base_seed is not None and args.base_seed < 0:
        fail(f"--base-seed must be >= 0, got {args.base_seed}", prog)


def run_options(args, toml_run: dict) -> dict:
    """``SweepSettings`` keyword arguments other than the points (command line over TOML)."""
    out = {k: v for k, v in toml_run.items()}
    for name in ("seeds", "base_seed", "method", "substeps"):
        if getattr(args, name) is not None:
            out[name] = getattr(args, name)
    return out


def requested(args):
    """``SweepSettings`` from the command line and ``--config``."""
    from armimp_jax.study import points as pts
    from armimp_jax.study.sweep import SweepSettings

    grid, points, run = pts.read_toml(args.config) if args.config else ({}, None, {})
    cli = pts.parse_set(args.set)
    both = sorted(set(cli) & set(grid))
    if both:
        raise ValueError(f"setting(s) {', '.join(both)} given both in --set and in {args.config}")
    grid = dict(grid) | cli
    for name in SHORTCUTS:
        value = getattr(args, name)
        if value is not None:
            if name in grid:
                raise ValueError(f"--{name} and --set {name} (or the TOML grid) both given")
            grid[name] = [value]
    return SweepSettings(tuple(pts.expand(grid, points)), **run_options(args, run))


def settings_for(args):
    """``(settings, out)``; for ``--resume`` the saved settings (options given must agree)."""
    from armimp_jax.study import engine
    from armimp_jax.study.points import normalize_point
    from armimp_jax.study.sweep import SweepSettings

    if args.resume is None:
        return requested(args), args.out
    saved = engine.saved_settings(SweepSettings, args.resume)
    if args.set or args.config:
        wanted = requested(args)
    else:  # options given with --resume apply to every saved point
        given = {k: getattr(args, k) for k in SHORTCUTS if getattr(args, k) is not None}
        points = tuple(normalize_point(dict(p) | given) for p in saved.points)
        wanted = dataclasses.replace(saved, points=points, **run_options(args, {}))
    engine.check_resume(args.resume, saved, wanted)
    return saved, args.resume


def run(args, *, prog: str = PROG, quiet: bool = False):
    """Run (or resume) a sweep from parsed options; returns ``(summary, out)`` (in a
    ``jax.distributed`` job, the processes other than 0 get only ``computed``)."""
    settings, out = settings_for(args)
    result = run_sweep(settings, out, prog=prog, batch_size=args.batch_size, check=args.check, x=args.x, quiet=quiet)
    return result, out


def main(argv=None):
    ap = parser()
    distributed = distributed_options()
    distributed.add_arguments(ap)
    args = ap.parse_args(argv)
    check_args(args)
    try:
        distributed.check_arguments(args)
    except ValueError as err:
        fail(str(err))
    distributed.initialize(args)  # before the backend starts (configure starts it)
    from armimp_jax.runtime import configure

    configure()
    try:
        result, _ = run(args)
    except ValueError as err:  # bad settings and ResultsError: one line, no traceback
        fail(str(err))
    if not distributed.is_writer():
        print(f"{PROG}: process {jax_process_index()} done; process 0 wrote the results")
        return 0
    return 0 if result["complete"] else 1


def jax_process_index() -> int:
    import jax

    return jax.process_index()


if __name__ == "__main__":
    sys.exit(main())
