"""General sweeps: a grid (or a list of points) over any settings of a trial, times seeds.

The points (``study.schema.points``: ``POINT_DEFAULTS``, ``Point``; read by ``study.schema.grids``: ``expand``,
``read_toml``, ``parse_set``) and ``SweepSettings`` fix a run. ``SweepSettings`` is a
specification of the study engine (``study.runs.engine``): ``run_sweep`` hands it to
``engine.run``, which runs every ``(point, seed)`` that has no valid record in the output
folder (batched by static structure, sharded over the devices, in chunks for progress) and
saves one checked record per trial (``study.runs.results``); ``write_outputs`` then writes
the tidy table ``trials.csv`` (one row per trial, ``trial_row``), ``summary.csv`` and
``summary.json`` (per point over seeds: mean, standard deviation, 95% t-interval, count
of diverged trials, which are left out of every statistic; ``study.sweep.stats``) and a figure
of ``phi_T`` against the swept quantity (``study.sweep.figures``). ``docs/sweeps.md``
describes the files. ``load_sweep`` and ``load_summary`` give the tables as pandas DataFrames from the checked records.

Seeds (``study.runs.seeds``): trial seed ``s`` draws its perturbation from
``fold_in(PRNGKey(base_seed), s)`` (every point sees the same signal shape for the same
seed: common random numbers) and its sensor noise, if any, from ``fold_in`` of that key
with 1.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable, Mapping

import jax
import numpy as np
import pandas as pd

from ..._batch import check_numerics
from ..._estimation.fit import fit_impedance
from ..._simulate import stack_trials
from ..._solver.numerics import SWEEP_NUMERICS, Numerics, named_solver
from ..runs import distributed, engine
from ..runs.console import Console
from ..runs.results import ResultsError, atomic_write_json, describe_difference, read_json, stamped, to_jsonable
from ..runs.runfolder import StudyRun, warn_stderr
from ..schema.grids import expand, parse_set, read_toml
from ..schema.points import Point, default_x, known_settings, swept_settings
from .figures import plot_summary
from .metrics import estimate_arrays, trial_row
from .stats import seed_stats
from .tables import METRIC_COLUMNS, summary_frame, trial_columns, trials_frame, write_table

# --- run settings ---------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class SweepSettings(engine.SimulationSpec):
    """Everything that fixes a sweep's numbers: its normalized ``points`` (``expand``), the
    number of ``seeds`` per point from ``base_seed``, and the integration ``method`` and
    ``substeps`` per 1 ms period (default ``SWEEP_NUMERICS``). A specification of the
    study engine (``study.runs.engine.Spec``): a trial is ``(point index, seed)``."""

    KIND = "sweep"
    FORMAT = 1  # layout of a sweep's run.json
    NOUN = "sweep"

    points: tuple[Point, ...]
    seeds: int = 3
    base_seed: int = 0
    method: str = SWEEP_NUMERICS.method
    substeps: int = SWEEP_NUMERICS.substeps

    def __post_init__(self):
        object.__setattr__(self, "points", tuple(Point.parse(p) for p in self.points))

    @property
    def numerics(self) -> Numerics:
        return Numerics(solver=named_solver(self.method), substeps=self.substeps)

    def validate(self) -> None:
        """Raise ``ValueError`` (one line) for settings that cannot run (the method and
        substeps are ``Numerics``'s to check)."""
        if not self.points:
            raise ValueError("a sweep needs at least one point")
        for name, minimum in (("seeds", 1), ("base_seed", 0)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
                raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
        _ = self.numerics  # Numerics checks the method and substeps

    def run_settings(self) -> dict:
        """As saved in ``run.json`` (package version included)."""
        return stamped(
            dict(
                points=[p.settings for p in self.points],
                seeds=self.seeds,
                base_seed=self.base_seed,
                numerics=self._numerics_dict(),
            )
        )

    def run_extra(self) -> dict:
        return {}

    def _numerics_dict(self) -> dict:
        return dict(method=self.method, substeps=self.substeps, kernel="fast")

    def trial_settings(self, point: Point, seed: int) -> dict:
        """Every value that changes one trial's numbers: its point, seed, base seed and numerics
        (the seed count, the other points and the batch size do not)."""
        return stamped(
            dict(point=point.settings, seed=int(seed), base_seed=self.base_seed, numerics=self._numerics_dict())
        )

    @classmethod
    def from_saved(cls, saved: Mapping, *, where: str = "run.json") -> SweepSettings:
        try:
            num = saved["numerics"]
            return cls(tuple(saved["points"]), saved["seeds"], saved["base_seed"], num["method"], num["substeps"])
        except (KeyError, TypeError, ValueError) as err:
            raise ResultsError(f"{where}: not the settings of a sweep ({err})") from None

    # --- the engine's specification ---

    @staticmethod
    def describe(saved: Mapping, wanted: Mapping) -> str:
        """One line saying how two sweeps' run settings differ (the points compared one by one)."""
        a, b = dict(saved), dict(wanted)
        pa, pb = a.pop("points"), b.pop("points")
        parts = [] if a == b else [describe_difference(a, b)]
        if len(pa) != len(pb):
            parts.append(f"{len(pa)} points (you asked {len(pb)})")
        for i, (x, y) in enumerate(zip(pa, pb, strict=False)):
            if x != y:
                parts.append(f"point {i}: {describe_difference(x, y, limit=3)}")
                break
        return ", ".join(parts) or "no difference"

    def trials(self) -> list[tuple[int, int]]:
        return [(i, s) for i in range(len(self.points)) for s in range(self.seeds)]

    def trial_record(self, trial: tuple[int, int]) -> tuple[str, dict]:
        i, s = trial
        return trial_id(self.points[i], s), self.trial_settings(self.points[i], s)

    def group(self, trial: tuple[int, int]) -> tuple:
        return self.points[trial[0]].group

    def samples(self, trial: tuple[int, int]) -> int:
        return self.points[trial[0]].samples

    def compile_key(self, batch: list) -> tuple:
        """A batch's compiled shape: its group, size and whether it draws sensor noise."""
        return self.group(batch[0]), len(batch), any(self.points[i].noisy for i, _ in batch)

    def build(self, batch, signals: engine.Perturbations) -> engine.Simulation:
        """The stacked trials of a batch of ``(point index, seed)`` sharing a ``static_group``,
        their perturbations and (if a point draws any) their sensor-noise keys."""
        points = [self.points[i] for i, _ in batch]
        n = points[0].samples
        f_delta = np.stack([signals(s, n, p["peak"]) for p, (_, s) in zip(points, batch, strict=True)])
        keys = np.stack([signals.noise_key(s) for _, s in batch]) if any(p.noisy for p in points) else None
        params = stack_trials([p.trial for p in points])
        return engine.Simulation(params, f_delta, self.numerics, keys, points[0].welch)

    def measure(self, batch, built, sim, outcome) -> list[tuple[dict, dict]]:
        """Per trial ``(arrays, meta)``: the estimate's arrays with the fit, and the record's
        meta (id, point index, seed, the ``trial_row`` metrics)."""
        points = [self.points[i] for i, _ in batch]
        fits = jax.tree.map(np.asarray, _vfit(outcome.estimate, acquisition=points[0]["acquisition"]))
        out = []
        for j, ((i, s), point) in enumerate(zip(batch, points, strict=True)):
            est = estimate_arrays(outcome.estimate, j)
            out_j = dict(
                est,
                phi_T=outcome.phi_T[j],
                phi_ij=outcome.phi_ij[j],
                input_coherence=outcome.input_coherence[j],
                diverged=sim.diverged[j],
                diverged_at=sim.diverged_at[j],
            )
            # the fit's numbers; its diagnostics restate the estimate's fields, which are saved already
            fit_j = {k: v[j] for k, v in fits._asdict().items() if k != "diagnostics"}
            meta = dict(id=trial_id(point, s), point_index=i, seed=s, metrics=trial_row(point.arm, out_j, fit_j))
            out.append((est | {f"fit_{k}": v for k, v in fit_j.items()}, meta))
        return out


def trial_id(point: Mapping, seed: int) -> str:
    """File name stem of a trial: a short hash of its point (stable across runs) and the seed."""
    return f"p{Point.parse(point).key}-s{seed}"


def saved_settings(out) -> SweepSettings:
    """The settings of the sweep in ``out`` (to resume it)."""
    return engine.resumed(SweepSettings, out)


def requested(config=None, sets=(), shortcuts: Mapping | None = None, run: Mapping | None = None) -> SweepSettings:
    """The sweep a command line asks for: the grid and points of the TOML file ``config``
    (``read_toml``), the ``--set`` options ``sets`` (``parse_set``), ``shortcuts`` (one value of
    a point setting each, e.g. ``seconds``) and ``run`` options (``seeds``, ``base_seed``,
    ``method``, ``substeps``: over the TOML's ``[run]``). A setting given twice is refused."""
    grid, points, toml_run = read_toml(config) if config else ({}, None, {})
    cli = parse_set(sets)
    both = sorted(set(cli) & set(grid))
    if both:
        raise ValueError(f"setting(s) {', '.join(both)} given both in --set and in {config}")
    grid = dict(grid) | cli
    for name, value in (shortcuts or {}).items():
        if name in grid:
            raise ValueError(f"--{name} and --set {name} (or the TOML file) both given")
        grid[name] = [value]
    return SweepSettings(tuple(expand(grid, points)), **(dict(toml_run) | dict(run or {})))


def resumed(out, config=None, sets=(), shortcuts: Mapping | None = None, run: Mapping | None = None) -> SweepSettings:
    """The settings of the sweep in ``out``, to finish it; options given as well (as
    ``requested``'s; shortcuts and run options apply to every saved point) must agree with
    them (one line naming the difference otherwise)."""

    def change(saved: SweepSettings) -> SweepSettings:
        if sets or config:
            return requested(config, sets, shortcuts, run)
        points = tuple(Point.parse(dict(p) | dict(shortcuts or {})) for p in saved.points)
        return dataclasses.replace(saved, points=points, **dict(run or {}))

    return engine.resumed(SweepSettings, out, change)


# --- per-trial fits ---------------------------------------------------------------------------


@functools.partial(jax.jit, static_argnames="acquisition")
def _vfit(estimates, *, acquisition: str):
    """M, B, K of a batch of estimates: the model of their acquisition, SEs from the estimator's
    own error model (bins correlated, variance per bin; docs/estimation.md)."""
    return jax.vmap(lambda e: fit_impedance(e, acquisition=acquisition, se="spectral"))(estimates)


# --- running ----------------------------------------------------------------------------------


# --- tables and statistics -------------------------------------------------------------------


def summarize(settings: SweepSettings, rows: list[dict]) -> list[dict]:
    """Per point: ``point`` (its settings), ``trials`` found, ``n`` sound, ``diverged`` (count
    and seeds), and for each of ``METRIC_COLUMNS`` the ``seed_stats`` over the sound seeds
    (diverged trials are left out of every statistic)."""
    by_point: dict[int, list] = {}
    for r in rows:
        by_point.setdefault(r["point_index"], []).append(r)
    out = []
    for i, point in enumerate(settings.points):
        rs = by_point.get(i, [])
        sound = [r for r in rs if not r["diverged"]]
        out.append(
            dict(
                point=point,
                trials=len(rs),
                n=len(sound),
                diverged=len(rs) - len(sound),
                diverged_seeds=[r["seed"] for r in rs if r["diverged"]],
                stats={m: seed_stats([r[m] for r in sound]) for m in METRIC_COLUMNS},
            )
        )
    return out


def collect(settings: SweepSettings, out, *, warn: Callable[[str], None] = warn_stderr) -> tuple[list[dict], list]:
    """The rows of every trial with a valid record in ``out`` (a ``StudyRun`` or a folder:
    ``point_index``, ``seed``, point columns, numerics, metrics), and the ``(point index,
    seed)`` pairs missing."""
    records, missing = engine.records(settings, out, warn=warn, note="recomputing it")
    rows = []
    num = dict(method=settings.method, substeps=settings.substeps)
    for (i, s), rec in sorted(records.items()):
        row = dict(point_index=i, seed=s, trial_id=rec.meta["id"]) | settings.points[i].columns
        rows.append(row | dict(base_seed=settings.base_seed) | num | rec.meta["metrics"])
    return rows, missing


def load_sweep(out, *, warn: Callable[[str], None] = warn_stderr) -> pd.DataFrame:
    """The trials of the sweep in folder ``out`` as a tidy DataFrame (one row per trial with a
    valid record; the columns of ``trials.csv``), read from the checked records."""
    settings = saved_settings(out)
    return trials_frame(collect(settings, out, warn=warn)[0], trial_columns(settings.points))


def load_summary(out, *, warn: Callable[[str], None] = warn_stderr) -> pd.DataFrame:
    """The per-point summary of the sweep in folder ``out`` as a DataFrame (the columns of
    ``summary.csv``), computed from the checked records."""
    settings = saved_settings(out)
    numerics = dict(method=settings.method, substeps=settings.substeps)
    return summary_frame(summarize(settings, collect(settings, out, warn=warn)[0]), numerics)


# --- the whole run ----------------------------------------------------------------------------


def numerics_check(settings: SweepSettings, rows: list[dict], sample: int, *, mesh=None) -> dict:
    """Re-run ``sample`` trials of each static group (spread over it) at 4x the substeps
    (``check_numerics``) and report the observed relative ``phi_T`` error."""
    signals = engine.Perturbations(settings.base_seed)
    by_group: dict[tuple, list] = {}
    for r in sorted(rows, key=lambda r: (r["point_index"], r["seed"])):
        by_group.setdefault(settings.points[r["point_index"]].group, []).append(r)
    picked = []
    for group in by_group.values():
        idx = np.unique(np.linspace(0, len(group) - 1, min(sample, len(group))).round().astype(int))
        picked += [group[j] for j in idx]

    def check(pick):  # one static group's sample, one batch
        built = settings.build([(r["point_index"], r["seed"]) for r in pick], signals)
        phi = np.array([math.nan if r["diverged"] else r["phi_T"] for r in pick])
        res = check_numerics(
            built.trials,
            built.f_delta,
            numerics=built.numerics,
            sample=len(pick),
            phi_T=phi,
            welch=built.welch,
            keys=built.keys,
            mesh=mesh,
        )
        return [(float(e), res.diverged if k == 0 else 0) for k, e in enumerate(res.rel_error)]

    group = lambda r: settings.points[r["point_index"]].group  # noqa: E731
    checked_rows = engine.map_batches(picked, group, max(sample, 1), check)
    errors = [e for e, _ in checked_rows if math.isfinite(e)]
    diverged, checked = sum(d for _, d in checked_rows), len(picked)
    return dict(
        sample_per_group=sample,
        trials_checked=checked,
        refined_substeps=settings.substeps * 4,
        max_rel_error=max(errors) if errors else None,
        diverged=diverged,
    )


def write_outputs(
    settings: SweepSettings, run: StudyRun, *, check: dict | None = None, x: str | None = None, warn=warn_stderr
) -> dict:
    """Write ``trials.csv``, ``summary.csv`` (and ``.parquet`` of both when ``pyarrow`` is
    importable), ``summary.json`` and the figure from the valid trial records of ``run``;
    returns the ``summary.json`` contents."""
    rows, missing = collect(settings, run, warn=warn)
    numerics = dict(method=settings.method, substeps=settings.substeps)
    write_table(trials_frame(rows, trial_columns(settings.points)), run.path / "trials.csv")
    summary = summarize(settings, rows)
    write_table(summary_frame(summary, numerics), run.path / "summary.csv")
    x = x or default_x(list(settings.points))
    figure = plot_summary(summary, run.path / f"{x or 'conditions'}.png", x=x) if rows else None
    saved = run.read()
    if check is None:  # keep the check of an earlier call on this run, if any
        try:
            previous = read_json(run.path / "summary.json")
            if isinstance(previous, dict) and previous.get("key") == saved["key"]:
                check = previous.get("numerics_check")
        except ResultsError:
            pass
    result = to_jsonable(
        dict(
            kind="sweep",
            format=settings.FORMAT,
            settings=saved["settings"],
            key=saved["key"],
            complete=not missing,
            trials_expected=len(settings.points) * settings.seeds,
            trials=len(rows),
            missing=[dict(point_index=i, seed=s) for i, s in missing],
            diverged=[r["trial_id"] for r in rows if r["diverged"]],
            swept=swept_settings(list(settings.points)),
            figure=None if figure is None else figure.name,
            numerics_check=check,
            conditions=summary,
        )
    )
    atomic_write_json(run.path / "summary.json", result)
    return result


def run_sweep(
    settings: SweepSettings,
    out,
    *,
    resume: bool = False,
    batch_size: int = 64,
    chunk_seconds: float = 5.0,
    check: int = 0,
    x: str | None = None,
    console: Console | None = None,
    stop_after_batches: int | None = None,
    warn: Callable[[str], None] = warn_stderr,
) -> dict:
    """Run a sweep in folder ``out`` (created if needed) on the study engine (``engine.run``)
    and write its tables and figure (``write_outputs``).

    Holds ``out``'s lock throughout; a folder holding a sweep with other settings is refused
    (one line naming the differences); trials with a valid record are reused, others
    (missing, truncated, altered, foreign: named in a warning) are computed. ``check`` > 0
    re-runs that many trials per static group at 4x the substeps and puts the observed
    maximum relative ``phi_T`` error into ``summary.json``. Returns the ``summary.json``
    contents plus ``computed`` (ids of the trials run now; in a ``jax.distributed`` job the
    processes other than 0 get only ``computed``). ``console`` (``study.runs.console``) says what
    runs where and shows the progress (default quiet).
    """
    settings.validate()
    if x is not None and x not in known_settings():
        raise ValueError(f"cannot plot against {x!r}: not a setting; known: {', '.join(known_settings())}")
    if batch_size < 1:
        raise ValueError(f"batch_size must be >= 1, got {batch_size}")
    if check > 0 and distributed.is_distributed():
        raise ValueError("check re-runs trials on one process: run it without the distributed options")

    console = Console(quiet=True) if console is None else console

    def header(on_disk: int, to_run: int) -> str:
        return (
            f"{len(settings.points)} point(s) x {settings.seeds} seed(s), {settings.method} with "
            f"{settings.substeps} substeps -> {out} ({on_disk} trials on disk, {to_run} to run)"
        )

    def finish(run: StudyRun, outcome) -> dict:
        console.end(len(outcome.computed))
        report = None
        if check > 0:
            rows, _ = collect(settings, run, warn=lambda _: None)
            report = numerics_check(settings, rows, check) if rows else None
        return write_outputs(settings, run, check=report, x=x, warn=lambda _: None)

    outcome = engine.run(
        settings,
        out,
        resume=resume,
        batch_size=batch_size,
        chunk_seconds=chunk_seconds,
        progress=console.progress,
        on_start=console.starter(header),
        finish=finish,
        warn=warn,
        stop_after_batches=stop_after_batches,
    )
    return (outcome.finished or {}) | dict(computed=outcome.computed)


def summary_lines(result: dict, out, seconds: float) -> list[str]:
    """What a script says when a sweep is done: the trials run, the diverged ones, the files,
    and the numerics check if one ran."""
    lines = [
        f"done in {seconds:.1f} s: {len(result['computed'])} trial(s) run, {len(result['diverged'])} diverged (left "
        f"out of the summary); {out}/trials.csv, summary.csv, {result['figure']}"
    ]
    chk = result.get("numerics_check")
    if chk:
        lines.append(
            f"numerics check: {chk['trials_checked']} trial(s) at {chk['refined_substeps']} substeps, "
            f"max relative phi_T error {chk['max_rel_error']}"
        )
    return lines
