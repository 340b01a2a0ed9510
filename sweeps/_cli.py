"""What the scripts share: one-line errors, the parser, the many-process options, and running a
sweep with a progress bar. Importing it imports no JAX (so ``--help`` stays fast): the
library is imported inside the functions that run something."""

from __future__ import annotations

import argparse
import sys
import time


def error_line(message: str, prog: str) -> int:
    """Write one line ``PROG: error: MESSAGE`` on stderr; return exit status 2 (for a ``main``
    that returns its status)."""
    sys.stderr.write(f"{prog}: error: {message}\n")
    return 2


def fail(message: str, prog: str):
    """One line ``PROG: error: MESSAGE`` on stderr and exit status 2 (no traceback)."""
    sys.exit(error_line(message, prog))


class Parser(argparse.ArgumentParser):
    """argparse with one-line errors (``PROG: error: ...``, exit status 2), under the
    parser's own ``prog``."""

    def error(self, message):
        fail(message, self.prog)


# The solvers' names, as ``Numerics.method`` and saved run settings spell them (spelled out
# here so that --help needs no JAX; tests/test_bench_helpers.py holds them to the library's).
METHODS = ("rk4", "ark3", "ark4", "gark4")


def solver(method: str, *, kernel: str = "fast"):
    """The solver named ``method`` (one of ``METHODS``) with RK4's ``kernel`` (or the kernel
    the others accept)."""
    import armimp_jax as aj

    return dict(zip(METHODS, (aj.RK4, aj.ARK3, aj.ARK4, aj.GradedARK4)))[method](kernel=kernel)


Z95 = 1.959963984540054  # the two-sided 95% normal quantile


def parse_cases(text: str, prog: str, example: str) -> list[tuple[str, float]]:
    """``--cases`` as ``[(controller, tau_c [N m]), ...]`` from ``"pd:0.3,imbic:1"``; one line
    (showing ``example``) and exit status 2 when it does not read so."""
    try:
        return [(c.split(":")[0], float(c.split(":")[1])) for c in text.split(",")]
    except (IndexError, ValueError):
        fail(f"--cases must look like {example}; got {text!r}", prog)


def bench_noise(aj, voluntary: float = 0.3) -> dict:
    """``make_trial``'s noise in the identification and design benchmarks: force noise 0.05 N,
    2^18-count encoders, and the person's own force, ``voluntary`` N RMS below 2 Hz."""
    return dict(sensors=aj.Sensors(force_noise=0.05, encoder_counts=2**18), voluntary=aj.VoluntaryForce(voluntary, 2.0))


def spread_and_hits(rows, name: str, true):
    """Over the saved ``rows`` of fits: the estimates ``e`` and SEs ``s`` of parameter ``name``
    (stacked over rows), the estimates' spread (SD, ``ddof=1``), and whether each 95% interval
    ``e +- Z95 s`` held the ``true`` value."""
    import numpy as np

    e = np.array([r["values"][name] for r in rows])
    s = np.array([r["se"][name] for r in rows])
    return e, s, e.std(axis=0, ddof=1), np.abs(e - true) <= Z95 * s


def resumable(path, settings: dict, prog: str, **empty):
    """A benchmark's saved state: the file at ``path`` when it holds the same ``settings`` (the
    run resumes), else a new state (``empty``'s entries and the stamped settings); one line
    and exit status 2 when the file holds other settings (a run never mixes them)."""
    from armimp_jax.study import read_json, stamped

    state = dict(settings=stamped(settings), **empty)
    if not path.exists():
        return state
    saved = read_json(path)
    if saved.get("settings") != state["settings"]:
        fail(f"{path} holds results of other settings; choose another --out", prog)
    done = sum(len(case.get("seeds", ())) for group in empty for case in saved.get(group, {}).values())
    print(f"resuming {path}: {done} recordings done", flush=True)
    return saved


def run_seeds(state, group: str, name: str, seeds: int, run_one, path, report=None) -> dict:
    """Run the seeds ``0 .. seeds - 1`` of case ``name`` (in ``state[group]``) that ``state``
    lacks, ``run_one(seed)`` each (a JSON-ready row with ``diverged``), saving ``state`` to
    ``path`` after every one (an interrupted run loses nothing); ``report(seed, row)`` is
    printed for each sound row. Returns the case."""
    from armimp_jax.study import atomic_write_json

    case = state[group].setdefault(name, dict(seeds=[]))
    done = {r["seed"] for r in case["seeds"]}
    for seed in range(seeds):
        if seed in done:
            continue
        row = run_one(seed)
        case["seeds"].append(row)
        atomic_write_json(path, state)
        if report is not None and not row["diverged"]:
            print(report(seed, row), flush=True)
    return case


def distributed_options():
    """``armimp_jax.study.distributed``, for its option helpers (``add_arguments``,
    ``check_arguments``): they need no JAX (the module imports it only to start a job)."""
    from armimp_jax.study import distributed

    return distributed


class Progress:
    """A tqdm bar in trials, with the library's ETA (compilation excluded); ends at 100%."""

    def __init__(self, total: int):
        from tqdm import tqdm

        self.bar = tqdm(
            total=total, unit="trial", bar_format="{l_bar}{bar}| {n:.1f}/{total_fmt} trials [{elapsed}{postfix}]"
        )

    def __call__(self, p):
        self.bar.n = p["trials_total"] * p["done"] / p["total"] if p["total"] else 0.0
        eta = p["eta_s"]
        self.bar.set_postfix_str(
            f"ETA {int(eta // 60)}:{int(eta % 60):02d}" if eta == eta else "ETA ? (compiling)", refresh=False
        )
        self.bar.refresh()

    def close(self):
        self.bar.n = self.bar.total
        self.bar.set_postfix_str("done", refresh=False)
        self.bar.close()


def run_sweep(
    settings, out, *, prog: str, batch_size: int = 64, check: int = 0, x: str | None = None, quiet: bool = False
) -> dict:
    """Run (or resume) the sweep of ``settings`` (``SweepSettings``) in folder ``out`` with a
    progress bar, saying what it does; returns ``run_sweep``'s result (in a
    ``jax.distributed`` job, the processes other than 0 get only ``computed``)."""
    from armimp_jax.study import distributed, sweep

    settings.validate()
    bar = None

    def on_start(on_disk: int, to_run: int):
        nonlocal bar
        if quiet:
            return
        print(
            f"{len(settings.points)} point(s) x {settings.seeds} seed(s), {settings.method} with "
            f"{settings.substeps} substeps -> {out} ({on_disk} trials on disk, {to_run} to run)",
            flush=True,
        )
        bar = Progress(to_run) if to_run else None

    start = time.perf_counter()
    try:
        result = sweep.run_sweep(
            settings,
            out,
            batch_size=batch_size,
            check=check,
            x=x,
            progress=lambda p: bar(p) if bar is not None else None,
            warn=lambda m: sys.stderr.write(f"{prog}: warning: {m}\n"),
            on_start=on_start,
        )
    finally:
        if bar is not None:
            bar.close()
    if not distributed.is_writer() or quiet:
        return result
    print(
        f"done in {time.perf_counter() - start:.1f} s: {len(result['computed'])} trial(s) run, "
        f"{len(result['diverged'])} diverged (left out of the summary); {out}/trials.csv, summary.csv, "
        f"{result['figure']}"
    )
    chk = result.get("numerics_check")
    if chk:
        print(
            f"numerics check: {chk['trials_checked']} trial(s) at {chk['refined_substeps']} substeps, "
            f"max relative phi_T error {chk['max_rel_error']}"
        )
    return result
