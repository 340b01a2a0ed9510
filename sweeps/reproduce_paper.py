"""Reproduce the paper end to end: PD and IMBIC sweeps over several seeds, figures, a report.

    python sweeps/reproduce_paper.py                 # the paper's settings (50 s, 100 substeps, Table 4), 3 seeds
    python sweeps/reproduce_paper.py --quick         # a smoke run in well under a minute
    python sweeps/reproduce_paper.py --seeds 5       # every condition over 5 perturbation seeds
    python sweeps/reproduce_paper.py --resume DIR    # finish an interrupted run with its own settings
    python sweeps/reproduce_paper.py --replot DIR    # redraw figures and report from saved results
    python sweeps/reproduce_paper.py --coordinator HOST:PORT --num-processes N --process-id I
                                                     # one process of an N-process job (docs/cluster.md)

Writes ``DIR/REPORT.md``, PNG figures, ``results.json`` / ``results.npz``, ``run.json`` (the
run's settings and their key) and one checked record per finished trial under
``DIR/trials`` (default DIR: results/paper or results/paper-quick). A folder holds one
run: a command with the same settings reuses its finished trials, one with other settings
is refused, and so is a folder another run is using (docs/results.md). In a job of several
processes (``--coordinator``/``--num-processes``/``--process-id`` or ``--auto-cluster``) every
process computes its shards of every batch and process 0 alone writes DIR.
"""

from __future__ import annotations

import dataclasses
import pathlib
import sys
import time

from armimp_jax.study.runs.cli import Parser, distributed_options, script
from armimp_jax.study.runs.cli import fail as cli_fail

PROG = "reproduce_paper"
DEFAULT_SEEDS = 3  # keep equal to armimp_jax.paper.reproduce.DEFAULT_SEEDS (read here before importing jax)
QUICK = dict(seconds=6.0, substeps=10, nperseg=1024, noverlap=768)
LEVELS = dict(locations=(1, 2, 3, 4), frictions=(0, 1, 2), perturbations=(1, 2, 3))
# options that change the numbers, as ReproSettings fields (None: not given on the command line)
SETTING_OPTIONS = (
    "seconds",
    "substeps",
    "nperseg",
    "noverlap",
    "seeds",
    "base_seed",
    "mhat",
    "locations",
    "frictions",
    "perturbations",
    "max_input_coherence",
)


def fail(message: str):
    cli_fail(message, PROG)


def parse(argv):
    ap = Parser(prog=PROG, description=__doc__)
    ap.add_argument("--quick", action="store_true", default=None, help="6 s records, 10 substeps, 1024-sample segments")
    ap.add_argument("--seeds", type=int, help=f"perturbation seeds per condition (default {DEFAULT_SEEDS})")
    ap.add_argument("--base-seed", type=int, help="seed of the PRNG the perturbations are folded from (default 0)")
    ap.add_argument("--seconds", type=float, help="record length [s] (default 50; quick 6)")
    ap.add_argument("--substeps", type=int, help="RK4 substeps per 1 ms (default 100; quick 10)")
    ap.add_argument("--nperseg", type=int, help="Welch segment [samples] (default 8192; quick 1024)")
    ap.add_argument("--noverlap", type=int, help="Welch overlap [samples] (default 6144; quick 768)")
    ap.add_argument("--mhat", type=float, help="IMBIC gain, times the identity [kg] (default 0.25)")
    ap.add_argument("--locations", type=int, nargs="+", help="IMBIC arm locations (default 1 2 3 4)")
    ap.add_argument("--frictions", type=int, nargs="+", help="friction levels (default 0 1 2)")
    ap.add_argument("--perturbations", type=int, nargs="+", help="PD perturbation levels (default 1 2 3)")
    ap.add_argument("--no-ablation", action="store_true", default=None, help="skip the interval-mean acquisition")
    ap.add_argument("--max-input-coherence", type=float, help="redraw perturbations until below (paper: 0.4)")
    ap.add_argument("--batch-size", type=int, default=48, help="trials per vmapped batch (does not change results)")
    ap.add_argument("--out", type=pathlib.Path, help="output folder")
    ap.add_argument("--resume", type=pathlib.Path, metavar="DIR", help="finish the run in DIR with its own settings")
    ap.add_argument("--replot", type=pathlib.Path, metavar="DIR", help="redraw figures and report from DIR")
    distributed_options().add_arguments(ap)
    return ap.parse_args(argv)


def requested(args) -> dict:
    """The settings given on the command line (``--quick`` stands for its four)."""
    out = dict(QUICK) if args.quick else {}
    out |= {k: getattr(args, k) for k in SETTING_OPTIONS if getattr(args, k) is not None}
    if args.no_ablation:
        out["ablation"] = False
    return out


def check_args(args) -> None:
    """Checks that need no simulation (run before JAX is imported)."""
    modes = [name for name in ("out", "resume", "replot") if getattr(args, name) is not None]
    if len(modes) > 1:
        fail(f"give one of --out, --resume and --replot, not {' and '.join('--' + m for m in modes)}")
    for name, allowed in LEVELS.items():
        bad = [v for v in getattr(args, name) or () if v not in allowed]
        if bad:
            fail(f"unknown {name[:-1]} level(s) {bad}; allowed: {', '.join(map(str, allowed))}")
    if args.batch_size < 1:
        fail(f"--batch-size must be >= 1, got {args.batch_size}")
    if args.seeds is not None and args.seeds < 1:
        fail(f"--seeds must be >= 1, got {args.seeds}")
    for name in ("resume", "replot"):
        folder = getattr(args, name)
        if folder is not None and not folder.is_dir():
            fail(f"--{name} {folder}: no such folder")
    if args.replot is not None and requested(args):
        fail("--replot redraws a finished run: it takes no simulation options")
    try:
        distributed_options().check_arguments(args)
    except ValueError as err:
        fail(str(err))
    if args.replot is not None and (args.coordinator or args.num_processes or args.auto_cluster):
        fail("--replot runs in one process: drop --coordinator, --num-processes, --process-id and --auto-cluster")


def settings_for(args, repro):
    """``(settings, out)``: from the command line, or for ``--resume`` from the run's
    ``run.json`` (options given as well must agree with it)."""
    asked = requested(args)
    if args.resume is None:
        out = args.out or pathlib.Path("results/paper-quick" if args.quick else "results/paper")
        return repro.ReproSettings(**asked), out
    from armimp_jax.study.runs import engine

    saved = engine.resumed(repro.ReproSettings, args.resume, lambda saved: dataclasses.replace(saved, **asked))
    return saved, args.resume


@script(PROG)
def main(argv=None) -> int:
    start = time.perf_counter()  # the recorded wall time covers the whole command
    args = parse(argv)
    check_args(args)
    from armimp_jax.study.runs import distributed

    distributed.initialize(args)  # before the backend starts (configure starts it)
    from armimp_jax.runtime import configure

    configure()
    from armimp_jax.paper import reproduce as repro
    from armimp_jax.study.runs.console import Console

    console = Console()
    if args.replot:
        figures, path = repro.replot(args.replot, console=console)
        print(f"redrew {len(figures)} figures and {path}")
        return 0
    settings, out = settings_for(args, repro)
    outcome = repro.reproduce(
        settings,
        out,
        resume=args.resume is not None,
        batch_size=args.batch_size,
        console=console,
        warn=console.warn(PROG),
        started=start,
    )
    if not distributed.is_writer():
        import jax

        shards = f"computed its shards of {len(outcome.todo)} trial(s)"
        print(f"process {jax.process_index()}: {shards}; process 0 writes {out}")
        return 0
    results, path = outcome.finished
    if outcome.interrupted:
        sys.stderr.write("\ninterrupted: finished trials are saved\n")
        print(f"partial report: {path}\nresume with: python sweeps/reproduce_paper.py --resume {out}")
        return 130
    for c in results["claims"]:
        print(f"  ({c['key']}) {c['verdict']:10s} {c['ours']}\n      {'':10s} {c['robustness']}")
    if results["diverged"]:
        print(f"  {len(results['diverged'])} diverged trial(s) left out of the means and claims (see the report)")
    if not results["complete"]:
        print(f"  incomplete: {len(results['missing'])} trial(s) missing; --resume {out} to finish")
    print(f"done in {time.perf_counter() - start:.1f} s: {path}")
    return 0 if results["complete"] else 1


if __name__ == "__main__":
    sys.exit(main())
