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

import argparse
import dataclasses
import itertools
import pathlib
import statistics
import sys
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from _cli import Parser, distributed_options  # noqa: E402
from _cli import fail as cli_fail  # noqa: E402

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
    ap = Parser(prog=PROG, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
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


def _clock(seconds: float) -> str:
    return f"{int(seconds // 60)}:{int(seconds % 60):02d}"


class ProgressBar:
    """The run's progress on one line of ``stream``, then its finishing steps, one line each.

    The ETA leaves compilation out: it counts the rate over the chunks that did not start a
    batch (a batch's first chunk also compiles it, after the previous batch's estimation),
    plus the measured cost of each batch start for the batches still to come; until a
    steady rate is known it says "compiling". The bar ends at 100% with every trial.
    """

    def __init__(self, trials_total: int, batches: list[int], per_trial: int, stream=sys.stderr):
        self.stream, self.trials_total, self.per_trial = stream, trials_total, per_trial
        self.ends = [per_trial * v for v in itertools.accumulate(batches)]
        self.total = per_trial * trials_total
        self.start = time.monotonic()
        self.last_draw = -1.0
        self.prev = None  # (time, done, trials_done) of the previous call
        self.steady_s = self.steady_work = 0.0  # time and trial samples of chunks that did not start a batch
        self.starts: list[float] = []  # measured extra cost of starting a batch (estimation, compilation)

    def begin(self) -> None:
        first = f" ({self.ends[0] // self.per_trial} trials)" if self.ends else ""
        self._draw(0, 0, f"compiling the first batch{first}...", force=True)

    def _rate(self):
        return self.steady_work / self.steady_s if self.steady_s > 0 and self.steady_work > 0 else None

    def __call__(self, p: dict) -> None:
        now = time.monotonic()
        done, trials = p["done"], p["trials_done"]
        rate = self._rate()
        if self.prev is not None:
            t_prev, done_prev, trials_prev = self.prev
            if trials == trials_prev:
                self.steady_s += now - t_prev
                self.steady_work += done - done_prev
            elif rate is not None:  # a batch started: what it cost beyond its simulation
                self.starts.append(max(0.0, now - t_prev - (done - done_prev) / rate))
        self.prev = (now, done, trials)
        rate = self._rate()
        batch = sum(1 for e in self.ends if e <= done)  # batches whose simulation is over
        if done >= self.total:
            status = "simulated; estimating the last batch..."
        elif done in self.ends:
            status = f"estimating batch {batch}/{len(self.ends)}, then compiling the next..."
        elif rate is None:  # the first chunk (and compilation) is over; the rate needs one more
            status = "ETA after the next chunk"
        else:
            per_start = statistics.fmean(self.starts) if self.starts else 0.0
            eta = (self.total - done) / rate + per_start * max(0, len(self.ends) - batch - 1)
            status = f"ETA {_clock(eta)}"
        self._draw(done, trials, status, force=done in self.ends or done >= self.total)

    def _draw(self, done, trials, status, *, force=False) -> None:
        now = time.monotonic()
        if not force and now - self.last_draw < 0.5:
            return
        self.last_draw = now
        frac = min(1.0, done / self.total) if self.total else 1.0
        bar = "#" * int(30 * frac) + "." * (30 - int(30 * frac))
        self.stream.write(
            f"\r[{bar}] {100 * frac:5.1f}%  trials {trials}/{self.trials_total}  "
            f"elapsed {_clock(now - self.start)}  {status:<50s}"
        )
        self.stream.flush()

    def end(self, trials_done: int) -> None:
        """The last line of the bar: every trial simulated, estimated and saved."""
        self._draw(self.total, trials_done, "done", force=True)
        self.stream.write("\n")
        self.stream.flush()


def step(name: str, fn, stream=sys.stderr):
    """Run ``fn()``, one finishing step, saying what it is and how long it took."""
    stream.write(f"{name}...")
    stream.flush()
    t0 = time.perf_counter()
    result = fn()
    stream.write(f" {time.perf_counter() - t0:.1f} s\n")
    stream.flush()
    return result


def warn(message: str) -> None:
    sys.stderr.write(f"{PROG}: warning: {message}\n")


def finish(repro, plots, report, out, start: float):
    """Aggregate, plot and write the report; the run's recorded wall time gains everything
    this command did since ``start`` (``time.perf_counter()`` when it began), the report's
    writing aside."""
    results, arrays = step("aggregating", lambda: repro.aggregate(out, warn=warn))
    figures = step("plotting", lambda: plots.all_figures(results, arrays, out))
    repro.record_wall_time(out, results, time.perf_counter() - start)
    path = step("writing the report", lambda: report.write_report(results, out, figures))
    return results, path


def settings_for(args, repro):
    """``(settings, out)``: from the command line, or for ``--resume`` from the run's
    ``run.json`` (options given as well must agree with it)."""
    asked = requested(args)
    if args.resume is None:
        out = args.out or pathlib.Path("results/paper-quick" if args.quick else "results/paper")
        return repro.ReproSettings(**asked), out
    from armimp_jax.study import engine

    saved = engine.saved_settings(repro.ReproSettings, args.resume)
    engine.check_resume(args.resume, saved, dataclasses.replace(saved, **asked))
    return saved, args.resume


def main(argv=None):
    start = time.perf_counter()  # the recorded wall time covers the whole command
    args = parse(argv)
    check_args(args)
    from armimp_jax.study import distributed

    distributed.initialize(args)  # before the backend starts (configure starts it)
    from armimp_jax.runtime import configure

    configure()
    from armimp_jax.paper import plots, report
    from armimp_jax.paper import reproduce as repro
    from armimp_jax.study import engine

    if args.replot:
        with engine.run_folder(repro.ReproSettings, args.replot).lock():
            results, arrays = repro.load_results(args.replot)
            figures = step("plotting", lambda: plots.all_figures(results, arrays, args.replot))
            path = step("writing the report", lambda: report.write_report(results, args.replot, figures))
            print(f"redrew {len(figures)} figures and {path}")
        return 0
    settings, out = settings_for(args, repro)
    settings.validate()
    writer = distributed.is_writer()
    # the writer holds the lock and reads the folder; every process gets its list of trials to run
    with engine.open_study(settings, out, resume=args.resume is not None, warn=warn) as (done, todo):
        if writer:
            print(
                f"{len(settings.conditions)} conditions x {settings.seeds} seed(s), {settings.seconds:g} s records, "
                f"{settings.substeps} substeps -> {out} ({len(done)} trials on disk, {len(todo)} to run)",
                flush=True,
            )
        bar = None
        if writer and todo:
            sizes = [len(b) for b in engine.batches(todo, settings.group, args.batch_size)]
            bar = ProgressBar(len(todo), sizes, settings.n_samples)
            bar.begin()
        try:
            computed = repro.run_reproduction(
                settings,
                out,
                batch_size=args.batch_size,
                chunk_seconds=min(5.0, settings.seconds),
                progress=bar,
                warn=lambda _: None,  # the scan above named every record that failed its check
            )
        except KeyboardInterrupt:
            if not writer:
                raise
            sys.stderr.write("\ninterrupted: finished trials are saved\n")
            _, path = finish(repro, plots, report, out, start)
            print(f"partial report: {path}\nresume with: python sweeps/reproduce_paper.py --resume {out}")
            return 130
        if not writer:
            import jax

            print(f"process {jax.process_index()}: computed its shards of {len(todo)} trial(s); process 0 writes {out}")
            return 0
        if bar is not None:
            bar.end(len(computed))
        results, path = finish(repro, plots, report, out, start)
    for c in results["claims"]:
        print(f"  ({c['key']}) {c['verdict']:10s} {c['ours']}\n      {'':10s} {c['robustness']}")
    if results["diverged"]:
        print(f"  {len(results['diverged'])} diverged trial(s) left out of the means and claims (see the report)")
    if not results["complete"]:
        print(f"  incomplete: {len(results['missing'])} trial(s) missing; --resume {out} to finish")
    print(f"done in {time.perf_counter() - start:.1f} s: {path}")
    return 0 if results["complete"] else 1


if __name__ == "__main__":
    try:
        sys.exit(main())
    except ValueError as err:  # bad settings and ResultsError: one line, no traceback
        fail(str(err))
