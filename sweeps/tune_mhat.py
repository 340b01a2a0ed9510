"""Tune IMBIC's gain Mhat by gradient descent on phi_T through the whole simulator.

    python sweeps/tune_mhat.py                     # 30 Adam steps on 16 s records, held-out eval at paper settings
    python sweeps/tune_mhat.py --quick             # a smoke run (tiny records, 3 steps)
    python sweeps/tune_mhat.py --resume DIR        # continue from the last saved iteration, with its settings

Writes DIR/mhat.json (the tuned gain), DIR/loss_curve.png, DIR/comparison.md and .json
(phi_T of the tuned Mhat vs hand-picked ones on held-out seeds, every location and
friction level) and the resumable state DIR/tune_state.npz (one checked file holding the
optimiser state and the settings that produced it). Default DIR: results/tune.

A folder holds one tuning run: a command with the same training settings continues it
(``--iterations`` may grow), one with other settings is refused, and so is a folder that
another run is using (docs/results.md).
"""

from __future__ import annotations

import argparse
import json
import pathlib
import shlex
import sys
import time
from typing import NamedTuple

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from _cli import Parser  # noqa: E402
from _cli import fail as cli_fail  # noqa: E402

PROG = "tune_mhat"
STATE = "tune_state.npz"
RUN_KIND, RUN_FORMAT = "tuning", 1  # run.json of a tuning folder
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


def fail(message: str):
    cli_fail(message, PROG)


def parse(argv):
    d = DEFAULTS
    ap = Parser(prog=PROG, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
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
        fail("give --out or --resume, not both")
    if args.resume is not None and not args.resume.is_dir():
        fail(f"--resume {args.resume}: no such folder")
    for name, minimum in (("iterations", 0), ("train_substeps", 1), ("train_seeds", 1), ("eval_seeds", 1)):
        value = getattr(args, name)
        if value is not None and value < minimum:
            fail(f"--{name.replace('_', '-')} must be >= {minimum}, got {value}")
    if args.eval_every is not None and args.eval_every < 0:
        fail(f"--eval-every must be >= 0, got {args.eval_every}")
    for name in ("start", "train_seconds"):
        value = getattr(args, name)
        if value is not None and not value > 0:
            fail(f"--{name.replace('_', '-')} must be > 0, got {value}")
    if args.compare is not None and not all(v > 0 for v in args.compare):
        fail(f"--compare values must be > 0 kg, got {args.compare}")
    bad = [f for f in args.frictions or () if f not in (0, 1, 2)]
    if bad:
        fail(f"unknown friction level(s) {bad}; allowed: 0, 1, 2")


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


def run_folder(out: pathlib.Path):
    """The tuning run's folder (``armimp_jax.study.runfolder``): its ``run.json`` holds the
    training settings, their key, and the options of the last command that ran it."""
    from armimp_jax.study.runfolder import StudyRun

    return StudyRun(out, kind=RUN_KIND, format=RUN_FORMAT, noun="tuning run", records=None)


def setup(options: dict, tune, paper_tune, Welch):
    """``(config, train, evals, locations, eval_every, settings)`` of a run with ``options``."""
    import numpy as np

    if options["quick"]:
        # 20 substeps: fewer put RK4 near its stability limit on the stiff LuGre bristles
        train = dict(seconds=2.5, substeps=20, welch=Welch(512, 384))
        evals = dict(seconds=2.5, substeps=20, welch=Welch(512, 384))
        iterations, eval_every, locations = min(options["iterations"], 3), 0, (1, 2)
    else:
        nperseg = options["train_nperseg"]
        train = dict(
            seconds=options["train_seconds"], substeps=options["train_substeps"], welch=Welch(nperseg, 3 * nperseg // 4)
        )
        evals = dict(seconds=50.0, substeps=100, welch=Welch())
        iterations, eval_every, locations = options["iterations"], options["eval_every"], (1, 2, 3, 4)
    config = tune.TuneConfig(
        parameterisation=options["parameterisation"],
        learning_rate=options["lr"],
        iterations=iterations,
        mode=options["mode"],
        phi_ij_weight=options["phi_ij_weight"],
        numerics=paper_tune.training_numerics(train["substeps"]),
    )
    settings = paper_tune.training_settings(
        config,
        frictions=options["frictions"],
        locations=locations,
        seeds=range(options["train_seeds"]),
        seconds=train["seconds"],
        welch=train["welch"],
        start_mhat=options["start"] * np.eye(2),
    )
    return config, train, evals, locations, eval_every, settings


class Run(NamedTuple):
    """A tuning run, set up: its options, training configuration, training and evaluation
    settings, arm locations, evaluation period, saved settings, and state (``None``: new)."""

    options: dict
    config: object
    train: dict
    evals: dict
    locations: tuple
    eval_every: int
    settings: dict
    state: object


def open_tuning(folder, out: pathlib.Path, args) -> Run:
    """The run in ``folder`` (locked by the caller): the options of the command (over those of
    the run resumed), checked against the folder's settings; its saved state, if any."""
    from armimp_jax import Welch
    from armimp_jax.paper import tune as paper_tune
    from armimp_jax.study import tune
    from armimp_jax.study.results import ResultsError, to_jsonable

    resumed = folder.read() if args.resume is not None else None
    options = DEFAULTS | (resumed["options"] if resumed else {}) | explicit(args)
    config, train, evals, locations, eval_every, settings = setup(options, tune, paper_tune, Welch)
    train["welch"].check(int(train["seconds"] * 1000))
    if resumed is not None:
        folder.check_resume(resumed["settings"], settings)
    run = folder.prepare(settings, resume=args.resume is not None, extra=dict(options=options))
    if run.get("options") != to_jsonable(options):  # a resume finds the options of the last command
        folder.update(options=options)
    state = None
    if (out / STATE).exists():
        try:
            state = tune.load_state(out / STATE, settings, config)
        except ResultsError as err:
            raise ResultsError(f"{err}; delete it to start over") from None
        print(f"continuing the tuning run in {out} from iteration {state.iteration}", flush=True)
    return Run(options, config, train, evals, locations, eval_every, settings, state)


def heldout(run: Run, mhats: dict) -> dict:
    """``paper_tune.heldout_phi`` of ``mhats`` at the run's evaluation settings."""
    from armimp_jax.paper import tune as paper_tune

    e = run.evals
    seeds = tuple(range(run.options["eval_seeds"]))
    return paper_tune.heldout_phi(
        mhats, locations=run.locations, seeds=seeds, seconds=e["seconds"], substeps=e["substeps"], welch=e["welch"]
    )


def train(run: Run, out: pathlib.Path):
    """Adam on the training batch from the run's state (or its start), saving the state after
    each step; ``(final state, perf_counter at the start of the steps)``, the state ``None``
    when interrupted (the saved state resumes it)."""
    import numpy as np

    from armimp_jax.paper import tune as paper_tune
    from armimp_jax.study import tune

    options, config = run.options, run.config
    params, f_delta = paper_tune.training_batch(
        tuple(options["frictions"]), run.locations, tuple(range(options["train_seeds"])), seconds=run.train["seconds"]
    )

    def evaluate(iteration, theta):
        phi = heldout(run, {"current": np.asarray(tune.mhat_from_theta(theta, config.parameterisation))})
        return dict(mean_phi_T=float(phi["current"].mean()), diverged=bool(phi["_diverged"]))

    def log(rec):
        keep = {k: (round(v, 4) if isinstance(v, float) else v) for k, v in rec.items() if k != "phi_T"}
        print(json.dumps(keep), flush=True)

    def save(st):
        tune.save_state(out / STATE, st, run.settings, meta=dict(options=options))

    print(
        f"training on {params.q0.shape[0]} trials of {run.train['seconds']:g} s ({run.train['substeps']} substeps), "
        f"{config.mode}-mode gradients -> {out}",
        flush=True,
    )
    start = time.perf_counter()
    theta0 = tune.theta_from_mhat(options["start"] * np.eye(2), config.parameterisation)
    try:
        state = tune.tune(
            theta0,
            params,
            f_delta,
            run.train["welch"],
            config,
            state=run.state,
            log=log,
            on_iteration=save,
            evaluate=evaluate,
            eval_every=run.eval_every,
        )
    except KeyboardInterrupt:
        return None, start
    save(state)
    return state, start


def write_outputs(run: Run, state, out: pathlib.Path, train_s: float):
    """``mhat.json``, ``loss_curve.png`` and the held-out comparison (``comparison.md`` and
    ``.json``) of the tuned gain against the hand-picked ones; returns ``(mhat, markdown)``."""
    import numpy as np

    from armimp_jax.paper import tune as paper_tune
    from armimp_jax.paper.plots import loss_curve
    from armimp_jax.study import tune
    from armimp_jax.study.results import atomic_write_json, atomic_write_text, settings_key

    mhat = np.asarray(tune.mhat_from_theta(state.theta, run.config.parameterisation))
    record = dict(mhat=mhat, settings=run.settings, key=settings_key(run.settings), iterations=state.iteration)
    atomic_write_json(out / "mhat.json", record | dict(train_loss=state.value, train_s=train_s))
    loss_curve(state.history.records(), out / "loss_curve.png")
    candidates = {"tuned": mhat} | {f"{v:g} I": v * np.eye(2) for v in run.options["compare"]}
    table = heldout(run, candidates)
    seeds = tuple(range(run.options["eval_seeds"]))
    md = paper_tune.comparison_markdown(table, mhat, locations=run.locations, evals=run.evals, seeds=seeds)
    atomic_write_text(out / "comparison.md", md)
    atomic_write_json(out / "comparison.json", table | dict(best=paper_tune.best_candidate(table)))
    return mhat, md


def main(argv=None):
    args = parse(argv)
    check_args(args)
    from armimp_jax.runtime import configure

    configure()
    import numpy as np

    out = args.resume or args.out or pathlib.Path("results/tune-quick" if args.quick else "results/tune")
    folder = run_folder(out)
    with folder.lock():
        run = open_tuning(folder, out, args)
        state, start = train(run, out)
        if state is None:
            print(f"interrupted; resume with:\n  {command_line(out, run.options)}")
            return 130
        mhat, md = write_outputs(run, state, out, time.perf_counter() - start)
    print(md)
    print(f"tuned Mhat = {np.round(mhat, 4).tolist()} kg; done in {time.perf_counter() - start:.0f} s")
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except ValueError as err:  # bad settings and ResultsError: one line, no traceback
        fail(str(err))
