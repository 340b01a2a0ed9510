"""Tune IMBIC's gain Mhat by gradient descent on phi_T through the whole simulator.

    python sweeps/tune_mhat.py                     # 30 Adam steps on 16 s records, held-out eval at paper settings
    python sweeps/tune_mhat.py --quick             # a smoke run (tiny records, 3 steps)
    python sweeps/tune_mhat.py --resume DIR        # continue from the last saved iteration, with its settings

Writes DIR/mhat.json (the tuned gain), DIR/loss_curve.png, DIR/comparison.md and .json
(phi_T of the tuned Mhat vs hand-picked ones on held-out seeds, every location and
friction level), DIR/run.json and one checked record per iteration under DIR/trials (the
optimiser's state after it, with the settings that produced it: a run resumes from the
last one). Default DIR: results/tune.

A folder holds one tuning run: a command with the same training settings continues it
(``--iterations`` may grow), one with other settings is refused, and so is a folder that
another run is using (docs/results.md).
"""

from __future__ import annotations

import json
import pathlib
import shlex
import sys

from armimp_jax.study.runs.cli import Parser, fail, script

PROG = "tune_mhat"
DEFAULTS = dict(
    quick=False,
    iterations=30,
    lr=0.1,
    parameterisation="diagonal",
    mode="reverse",
    start=0.25,
    phi_ij_weight=0.0,
    train_seconds=16.0,
    train_substeps=20,
    train_nperseg=4096,
    train_seeds=2,
    frictions=[1, 2],
    eval_every=10,
    eval_seeds=2,
    compare=[0.25, 0.5, 1.0, 1.5],
)


def parse(argv):
    d = DEFAULTS
    ap = Parser(prog=PROG, description=__doc__)
    ap.add_argument("--quick", action="store_true", default=None, help="2.5 s records, 2 locations, at most 3 steps")
    ap.add_argument(
        "--iterations", type=int, help=f"Adam steps in all, resumed ones included (default {d['iterations']})"
    )
    ap.add_argument("--lr", type=float, help=f"Adam learning rate, in log-Mhat units (default {d['lr']})")
    ap.add_argument("--parameterisation", choices=["diagonal", "full"], help="default diagonal")
    ap.add_argument(
        "--mode",
        choices=["forward", "reverse"],
        help="gradient mode (default reverse: 2x faster than forward in bench_gradient.py)",
    )
    ap.add_argument("--start", type=float, help=f"starting Mhat, times the identity [kg] (default {d['start']})")
    ap.add_argument("--phi-ij-weight", type=float, help="weight of mean phi_ij in the loss (default 0)")
    ap.add_argument("--train-seconds", type=float, help=f"training record length [s] (default {d['train_seconds']:g})")
    ap.add_argument("--train-substeps", type=int, help=f"training RK4 substeps (default {d['train_substeps']})")
    ap.add_argument("--train-nperseg", type=int, help=f"training Welch segment (default {d['train_nperseg']})")
    ap.add_argument("--train-seeds", type=int, help=f"training perturbation seeds (default {d['train_seeds']})")
    ap.add_argument("--frictions", type=int, nargs="+", help="training friction levels (default 1 2)")
    ap.add_argument("--eval-every", type=int, help="held-out evaluation every N steps (0: off; default 10)")
    ap.add_argument("--eval-seeds", type=int, help=f"held-out seeds (default {d['eval_seeds']})")
    ap.add_argument("--compare", type=float, nargs="+", help="hand-picked Mhat values (times I) for the final table")
    ap.add_argument("--out", type=pathlib.Path, help="output folder (default results/tune or results/tune-quick)")
    ap.add_argument("--resume", type=pathlib.Path, metavar="DIR", help="continue the tuning run in DIR")
    return ap.parse_args(argv)


def explicit(args) -> dict:
    """The options given on the command line."""
    return {k: getattr(args, k) for k in DEFAULTS if getattr(args, k) is not None}


def check_args(args) -> None:
    """Checks that need no simulation (run before JAX is imported)."""
    if args.out is not None and args.resume is not None:
        fail("give --out or --resume, not both", PROG)
    if args.resume is not None and not args.resume.is_dir():
        fail(f"--resume {args.resume}: no such folder", PROG)
    for name, minimum in (("iterations", 0), ("train_substeps", 1), ("train_seeds", 1), ("eval_seeds", 1)):
        value = getattr(args, name)
        if value is not None and value < minimum:
            fail(f"--{name.replace('_', '-')} must be >= {minimum}, got {value}", PROG)
    if args.eval_every is not None and args.eval_every < 0:
        fail(f"--eval-every must be >= 0, got {args.eval_every}", PROG)
    for name in ("start", "train_seconds"):
        value = getattr(args, name)
        if value is not None and not value > 0:
            fail(f"--{name.replace('_', '-')} must be > 0, got {value}", PROG)
    if args.compare is not None and not all(v > 0 for v in args.compare):
        fail(f"--compare values must be > 0 kg, got {args.compare}", PROG)
    bad = [f for f in args.frictions or () if f not in (0, 1, 2)]
    if bad:
        fail(f"unknown friction level(s) {bad}; allowed: 0, 1, 2", PROG)


def command_line(out: pathlib.Path, options: dict) -> str:
    """The full command that resumes the run in ``out`` with ``options``."""
    words = ["python", "sweeps/tune_mhat.py", "--resume", str(out)]
    for k, v in options.items():
        flag = "--" + k.replace("_", "-")
        if isinstance(v, bool):
            words += [flag] if v else []
        elif isinstance(v, list):
            words += [flag, *(f"{x:g}" if isinstance(x, float) else str(x) for x in v)]
        else:
            words += [flag, f"{v:g}" if isinstance(v, float) else str(v)]
    return shlex.join(words)


def log(rec: dict) -> None:
    """One optimiser record as a JSON line (floats rounded, the per-trial phi_T left out)."""
    keep = {k: (round(v, 4) if isinstance(v, float) else v) for k, v in rec.items() if k != "phi_T"}
    print(json.dumps(keep), flush=True)


@script(PROG)
def main(argv=None) -> int:
    args = parse(argv)
    check_args(args)
    from armimp_jax.runtime import configure

    configure()
    import numpy as np

    from armimp_jax.paper import mhat_experiment
    from armimp_jax.study.runs.console import Console

    out = args.resume or args.out or pathlib.Path("results/tune-quick" if args.quick else "results/tune")
    resume = args.resume is not None
    options = explicit(args) if resume else DEFAULTS | explicit(args)
    spec = mhat_experiment.tuning(options, out, resume=resume, log=log)
    outcome = mhat_experiment.tune_mhat(spec, out, resume=resume, console=Console())
    if outcome.finished is None:
        print(f"interrupted; resume with:\n  {command_line(out, spec.options)}")
        return 130
    mhat, md = outcome.finished
    print(md)
    print(f"tuned Mhat = {np.round(mhat, 4).tolist()} kg; {len(outcome.computed)} iteration(s) run now")
    return 0


if __name__ == "__main__":
    sys.exit(main())
