"""General sweeps: a grid (or a list of points) over any settings of a trial, times seeds.

The points (``study.points``: ``POINT_DEFAULTS``, ``normalize_point``, ``expand``,
``read_toml``, ``parse_set``) and ``SweepSettings`` fix a run. ``run_sweep`` runs every
``(point, seed)`` that has no valid record in the output folder (batched by static
structure, sharded over the devices, in chunks for progress), saves one checked record
per trial (``study.results``), then writes the tidy table ``trials.csv`` (one row per
trial), ``summary.csv``/``summary.json`` (per point over seeds: mean, standard
deviation, 95% t-interval, count of diverged trials, which are left out of every
statistic; ``study.stats``) and a figure of ``phi_T`` against the swept quantity
(``study.figures``). The folder follows the run-folder protocol (``study.runfolder``);
``docs/sweeps.md`` describes the files. ``load_sweep`` and ``load_summary`` give the
tables as pandas DataFrames from the checked records.

Seeds (``study.seeds``): trial seed ``s`` draws its perturbation from
``fold_in(PRNGKey(base_seed), s)`` (every point sees the same signal shape for the same
seed: common random numbers) and its sensor noise, if any, from ``fold_in`` of that key
with 1.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import pathlib
import time
from collections.abc import Callable, Mapping

import jax
import numpy as np
import pandas as pd

from .._batch import assess_batch, check_numerics, make_mesh, simulate_batch
from .._estimation.fit import fit_impedance
from .._simulate import stack_trials
from .._solver.numerics import METHODS, SWEEP_NUMERICS, Numerics, named_solver
from . import distributed
from .figures import plot_summary as plot_summary
from .points import (
    POINT_DEFAULTS,
    build_trial,
    default_x,
    n_samples,
    normalize_point,
    point_arm,
    point_columns,
    point_welch,
    static_group,
    swept_settings,
)
from .points import POINT_UNITS as POINT_UNITS
from .points import expand as expand
from .points import parse_set as parse_set
from .points import read_toml as read_toml
from .results import ResultsError, describe_difference, read_json, save_record, settings_key, stamped, to_jsonable
from .results import atomic_write_json as atomic_write_json
from .runfolder import RunFolder, open_run, warn_stderr
from .runfolder import trial_status as _record_status
from .seeds import seed_perturbation, sensor_noise_key
from .stats import CI_LEVEL as CI_LEVEL
from .stats import bootstrap_crossing as bootstrap_crossing
from .stats import first_crossing as first_crossing
from .stats import mean_ci as mean_ci
from .stats import seed_stats
from .tables import COH_COLUMNS as COH_COLUMNS
from .tables import ELEMENTS, METRIC_COLUMNS, summary_frame, summary_rows, trial_columns, trials_frame, write_table
from .tables import FIT_COLUMNS as FIT_COLUMNS
from .tables import SUMMARY_DTYPES as SUMMARY_DTYPES
from .tables import TRIAL_DTYPES as TRIAL_DTYPES
from .tables import write_csv as write_csv

RUN_KIND = "sweep"
RUN_FORMAT = 1  # layout of a sweep's run.json
ESTIMATE_FIELDS = ("f", "Z", "coh_multiple_x", "coh_partial_x", "coh_multiple_fh", "coh_partial_fh", "coh_inputs")


summary_table = summary_rows  # its name before study.tables


# --- run settings ---------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class SweepSettings:
    """Everything that fixes a sweep's numbers: its normalized ``points`` (``expand``), the
    number of ``seeds`` per point from ``base_seed``, and the integration ``method`` and
    ``substeps`` per 1 ms period (default ``SWEEP_NUMERICS``)."""

    points: tuple
    seeds: int = 3
    base_seed: int = 0
    method: str = SWEEP_NUMERICS.method
    substeps: int = SWEEP_NUMERICS.substeps

    def __post_init__(self):
        object.__setattr__(self, "points", tuple(normalize_point(p) for p in self.points))

    @property
    def numerics(self) -> Numerics:
        return Numerics(solver=named_solver(self.method), substeps=self.substeps)

    def validate(self) -> None:
        """Raise ``ValueError`` (one line) for settings that cannot run."""
        if not self.points:
            raise ValueError("a sweep needs at least one point")
        if isinstance(self.seeds, bool) or not isinstance(self.seeds, int) or self.seeds < 1:
            raise ValueError(f"seeds must be an integer >= 1, got {self.seeds!r}")
        if isinstance(self.base_seed, bool) or not isinstance(self.base_seed, int) or self.base_seed < 0:
            raise ValueError(f"base_seed must be an integer >= 0, got {self.base_seed!r}")
        if self.method not in METHODS:
            raise ValueError(f"method must be one of {', '.join(METHODS)}, got {self.method!r}")
        if isinstance(self.substeps, bool) or not isinstance(self.substeps, int) or self.substeps < 1:
            raise ValueError(f"substeps must be an integer >= 1, got {self.substeps!r}")

    def run_settings(self) -> dict:
        """As saved in ``run.json`` (package version included)."""
        return stamped(
            dict(points=list(self.points), seeds=self.seeds, base_seed=self.base_seed, numerics=self._numerics_dict())
        )

    def _numerics_dict(self) -> dict:
        return dict(method=self.method, substeps=self.substeps, kernel="fast")

    def trial_settings(self, point: Mapping, seed: int) -> dict:
        """Every value that changes one trial's numbers: its point, seed, base seed and numerics
        (the seed count, the other points and the batch size do not)."""
        return stamped(
            dict(point=dict(point), seed=int(seed), base_seed=self.base_seed, numerics=self._numerics_dict())
        )

    @classmethod
    def from_saved(cls, saved: Mapping, *, where: str = "run.json") -> SweepSettings:
        try:
            num = saved["numerics"]
            return cls(tuple(saved["points"]), saved["seeds"], saved["base_seed"], num["method"], num["substeps"])
        except (KeyError, TypeError, ValueError) as err:
            raise ResultsError(f"{where}: not the settings of a sweep ({err})") from None


def _describe(saved: Mapping, wanted: Mapping) -> str:
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


def describe_run_difference(saved: SweepSettings, wanted: SweepSettings) -> str:
    """One line saying how two sweeps differ (the points compared one by one)."""
    return _describe(saved.run_settings(), wanted.run_settings())


def trial_id(settings: SweepSettings, point: Mapping, seed: int) -> str:
    """File name stem of a trial: a short hash of its point (stable across runs) and the seed."""
    return f"p{settings_key(dict(point=dict(point)))[:12]}-s{seed}"


def run_folder(out) -> RunFolder:
    """The run folder ``out`` of a sweep (``study.runfolder``)."""
    return RunFolder(out, kind=RUN_KIND, format=RUN_FORMAT, noun="sweep")


def read_run(out) -> dict:
    """``run.json`` of the sweep in ``out``, checked (``ResultsError`` naming what is wrong)."""
    return run_folder(out).read()


def saved_settings(out) -> SweepSettings:
    """The settings of the sweep in ``out`` (to resume it)."""
    folder = run_folder(out)
    return SweepSettings.from_saved(folder.saved_settings(), where=str(folder.run_file))


def check_resume(out, saved: SweepSettings, wanted: SweepSettings) -> None:
    """Refuse (one line) options given with ``--resume out`` that change the sweep there."""
    run_folder(out).check_resume(saved.run_settings(), wanted.run_settings(), describe=_describe)


def prepare_output(out, settings: SweepSettings) -> None:
    """Create ``out`` and write ``run.json``, or check that the run there has ``settings``
    (a folder holding another sweep is refused in one line naming the differences)."""
    run_folder(out).prepare(settings.run_settings(), describe=_describe)


def _trials(settings: SweepSettings, out) -> list:
    """``((point index, seed), record path, trial settings)`` of every trial, in run order."""
    out = pathlib.Path(out)
    return [
        ((i, s), out / "trials" / f"{trial_id(settings, point, s)}.npz", settings.trial_settings(point, s))
        for i, point in enumerate(settings.points)
        for s in range(settings.seeds)
    ]


def trial_status(settings: SweepSettings, out, *, warn: Callable[[str], None] = warn_stderr):
    """``(records, todo)``: ``{(point index, seed): Record}`` of the trials whose record passes
    its check, and the ``(point index, seed)`` pairs still to run; every other existing
    record is named in a warning (it will be recomputed)."""
    return _record_status(_trials(settings, out), warn=warn)


# --- per-trial metrics ------------------------------------------------------------------------


def _cells(prefix: str, a) -> dict:
    a = np.asarray(a, dtype=float).reshape(-1)
    return {f"{prefix}_{e}": float(v) for e, v in zip(ELEMENTS, a, strict=True)}


def trial_metrics(point: Mapping, outcome_i: Mapping, fit_i: Mapping) -> dict:
    """The scalar columns of one trial (``METRIC_COLUMNS`` plus ``diverged``, ``diverged_at``).

    ``coh_min`` is the minimum over ``0 < f <= fmax`` of the four multiple coherences (both
    position outputs and both force outputs): the weakest of the spectra ``Z = T R^-1``
    is built from. ``rel_error`` is ``phi_T`` over the mean largest singular value of the
    arm's true impedance.
    """
    f = outcome_i["f"]
    zt = np.asarray(point_arm(point).impedance(f))
    scale = float(np.mean(np.linalg.svd(zt, compute_uv=False)[:, 0]))
    cx, cf = np.asarray(outcome_i["coh_multiple_x"]), np.asarray(outcome_i["coh_multiple_fh"])
    row = dict(phi_T=float(outcome_i["phi_T"]), **_cells("phi", outcome_i["phi_ij"]))
    row["rel_error"] = row["phi_T"] / scale
    row["coh_min"] = float(min(cx.min(), cf.min()))
    for name, c in (("x", cx), ("fh", cf)):
        for j in range(2):
            row[f"coh_{name}{j + 1}_min"] = float(c[:, j].min())
            row[f"coh_{name}{j + 1}_median"] = float(np.median(c[:, j]))
    row["input_coherence_max"] = float(outcome_i["input_coherence"])
    for p, field in (("M", "mass"), ("B", "damping"), ("K", "stiffness")):
        row |= _cells(p, fit_i[field])
        row |= {k + "_se": v for k, v in _cells(p, fit_i[field + "_se"]).items()}
    row |= _cells("vaf", fit_i["vaf"])
    row["vaf_overall"] = float(fit_i["vaf_overall"])
    row = {k: row[k] for k in METRIC_COLUMNS}
    row["diverged"] = bool(outcome_i["diverged"])
    row["diverged_at"] = int(outcome_i["diverged_at"])
    return row


@functools.partial(jax.jit, static_argnames="acquisition")
def _vfit(estimates, *, acquisition: str):
    """M, B, K of a batch of estimates: the model of their acquisition, SEs from the estimator's
    own error model (bins correlated, variance per bin; docs/estimation.md)."""
    return jax.vmap(lambda e: fit_impedance(e, acquisition=acquisition, se="spectral"))(estimates)


# --- running ----------------------------------------------------------------------------------


@dataclasses.dataclass
class _Perturbations:
    """The perturbations of a sweep's seeds, drawn once per (seed, length, peak)."""

    base_seed: int
    cache: dict = dataclasses.field(default_factory=dict)

    def noise_key(self, seed: int) -> np.ndarray:
        return sensor_noise_key(self.base_seed, seed)

    def __call__(self, seed: int, n: int, peak) -> np.ndarray:
        k = (seed, n, tuple(peak))
        if k not in self.cache:
            self.cache[k] = seed_perturbation(self.base_seed, seed, n, peak)
        return self.cache[k]


def _noisy(point) -> bool:
    return point["force_noise"] > 0 or point["velocity_noise"] > 0


def _batches(settings: SweepSettings, todo, batch_size: int) -> list[list]:
    groups: dict[tuple, list] = {}
    for i, s in todo:
        groups.setdefault(static_group(settings.points[i]), []).append((i, s))
    out = []
    for g in groups.values():  # equal batches: one compiled shape per group
        per = math.ceil(len(g) / math.ceil(len(g) / batch_size))
        out += [g[j : j + per] for j in range(0, len(g), per)]
    return out


def run_batch(settings: SweepSettings, batch, signals, *, mesh=None, chunk_seconds: float = 5.0, progress=None):
    """Simulate and assess one batch of ``(point index, seed)`` sharing a ``static_group``;
    returns ``(rows, arrays)``, per trial the metrics dict and the estimate's arrays."""
    points = [settings.points[i] for i, _ in batch]
    n = n_samples(points[0])
    params = stack_trials([build_trial(p) for p in points])
    f_delta = np.stack([signals(s, n, p["peak"]) for p, (_, s) in zip(points, batch, strict=True)])
    keys = np.stack([signals.noise_key(s) for _, s in batch]) if any(_noisy(p) for p in points) else None
    sim = simulate_batch(
        params,
        f_delta,
        keys=keys,
        numerics=settings.numerics,
        mesh=mesh,
        chunk_samples=max(1, int(chunk_seconds * 1000)),
        progress=progress,
    )
    outcome = assess_batch(params, f_delta, sim, point_welch(points[0]), mesh=mesh)
    fits = jax.tree.map(np.asarray, _vfit(outcome.estimate, acquisition=points[0]["acquisition"]))
    rows, arrays = [], []
    for j, point in enumerate(points):
        est = {name: np.asarray(getattr(outcome.estimate, name)[j]) for name in ESTIMATE_FIELDS}
        out_j = dict(
            est,
            phi_T=outcome.phi_T[j],
            phi_ij=outcome.phi_ij[j],
            input_coherence=outcome.input_coherence[j],
            diverged=sim.diverged[j],
            diverged_at=sim.diverged_at[j],
        )
        fit_j = {k: v[j] for k, v in fits._asdict().items()}
        rows.append(trial_metrics(point, out_j, fit_j))
        arrays.append(est | {f"fit_{k}": v for k, v in fit_j.items()})
    return rows, arrays


def compute(
    settings: SweepSettings,
    out,
    todo,
    *,
    batch_size: int = 64,
    chunk_seconds: float = 5.0,
    progress: Callable[[dict], None] | None = None,
    stop_after_batches: int | None = None,
) -> list[str]:
    """Run the ``todo`` trials in batches and save each as a checked record as soon as its
    batch finishes; returns the ids computed.

    ``progress`` receives a dict after every chunk: ``done``/``total`` (trial samples),
    ``trials_done``, ``trials_total``, ``elapsed_s`` and ``eta_s``, the latter from the
    rate of the chunks that compiled nothing (the first chunk of each new batch shape
    pays for compilation; NaN until a chunk has run without compiling)."""
    out = pathlib.Path(out)
    mesh = make_mesh()
    signals = _Perturbations(settings.base_seed)
    total = sum(n_samples(settings.points[i]) for i, _ in todo)
    start = time.perf_counter()
    # "last": when the previous chunk reported, so that estimating and saving a batch count
    # towards the rate (they are part of every trial's cost)
    state = dict(done=0, trials=0, t_fresh=0.0, n_fresh=0, last=start)
    shapes_seen: set = set()
    computed = []
    for b_index, batch in enumerate(_batches(settings, todo, batch_size)):
        if stop_after_batches is not None and b_index >= stop_after_batches:
            break
        shape = (
            static_group(settings.points[batch[0][0]]),
            len(batch),
            any(_noisy(settings.points[i]) for i, _ in batch),
        )
        compiling = [shape not in shapes_seen]
        shapes_seen.add(shape)
        base = state["done"]

        def on_chunk(done, _total, _elapsed, base=base, compiling=compiling):
            now = time.perf_counter()
            step = base + done - state["done"]
            if not compiling[0]:  # chunks that compiled nothing set the rate of the ETA
                state["t_fresh"] += now - state["last"]
                state["n_fresh"] += step
            compiling[0] = False
            state["last"] = now
            state["done"] = base + done
            if progress is not None:
                rate = state["n_fresh"] / state["t_fresh"] if state["t_fresh"] > 0 else float("nan")
                progress(
                    dict(
                        done=state["done"],
                        total=total,
                        trials_done=state["trials"],
                        trials_total=len(todo),
                        elapsed_s=now - start,
                        eta_s=(total - state["done"]) / rate if rate > 0 else float("nan"),
                    )
                )

        t0 = time.perf_counter()
        rows, arrays = run_batch(settings, batch, signals, mesh=mesh, chunk_seconds=chunk_seconds, progress=on_chunk)
        wall = time.perf_counter() - t0
        for (i, s), row, arr in zip(batch, rows, arrays, strict=True):
            point = settings.points[i]
            tid = trial_id(settings, point, s)
            meta = dict(id=tid, point_index=i, seed=s, metrics=row, batch_wall_s=wall, batch_size=len(batch))
            if distributed.is_writer():  # every process holds every row (gathered); one writes
                save_record(
                    out / "trials" / f"{tid}.npz", settings=settings.trial_settings(point, s), arrays=arr, meta=meta
                )
            computed.append(tid)
        state["trials"] += len(batch)
    return computed


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
    """The rows of every trial with a valid record (``point_index``, ``seed``, point columns,
    numerics, metrics), and the ``(point index, seed)`` pairs missing."""
    records, missing = trial_status(settings, out, warn=warn)
    rows = []
    num = dict(method=settings.method, substeps=settings.substeps)
    for (i, s), rec in sorted(records.items()):
        row = dict(point_index=i, seed=s, trial_id=rec.meta["id"]) | point_columns(settings.points[i])
        rows.append(row | dict(base_seed=settings.base_seed) | num | rec.meta["metrics"])
    return rows, missing


def load_sweep(out, *, warn: Callable[[str], None] = warn_stderr) -> pd.DataFrame:
    """The trials of the sweep in folder ``out`` as a tidy DataFrame (one row per trial with a
    valid record; the columns of ``trials.csv``), read from the checked records."""
    settings = saved_settings(out)
    return trials_frame(collect(settings, out, warn=warn)[0], trial_columns(settings.points[0]))


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
    signals = _Perturbations(settings.base_seed)
    by_group: dict[tuple, list] = {}
    for r in sorted(rows, key=lambda r: (r["point_index"], r["seed"])):
        by_group.setdefault(static_group(settings.points[r["point_index"]]), []).append(r)
    errors, diverged, checked = [], 0, 0
    for group in by_group.values():
        idx = np.unique(np.linspace(0, len(group) - 1, min(sample, len(group))).round().astype(int))
        pick = [group[j] for j in idx]
        points = [settings.points[r["point_index"]] for r in pick]
        params = stack_trials([build_trial(p) for p in points])
        n = n_samples(points[0])
        f_delta = np.stack([signals(r["seed"], n, p["peak"]) for r, p in zip(pick, points, strict=True)])
        keys = np.stack([signals.noise_key(r["seed"]) for r in pick]) if any(_noisy(p) for p in points) else None
        phi = np.array([math.nan if r["diverged"] else r["phi_T"] for r in pick])
        res = check_numerics(
            params,
            f_delta,
            numerics=settings.numerics,
            sample=len(pick),
            phi_T=phi,
            welch=point_welch(points[0]),
            keys=keys,
            mesh=mesh,
        )
        errors += [float(e) for e in res.rel_error if math.isfinite(e)]
        diverged += res.diverged
        checked += len(pick)
    return dict(
        sample_per_group=sample,
        trials_checked=checked,
        refined_substeps=settings.substeps * 4,
        max_rel_error=max(errors) if errors else None,
        diverged=diverged,
    )


def write_outputs(
    settings: SweepSettings, out, *, check: dict | None = None, x: str | None = None, warn=warn_stderr
) -> dict:
    """Write ``trials.csv``, ``summary.csv`` (and ``.parquet`` of both when ``pyarrow`` is
    importable), ``summary.json`` and the figure from the valid trial records in ``out``;
    returns the ``summary.json`` contents."""
    out = pathlib.Path(out)
    rows, missing = collect(settings, out, warn=warn)
    numerics = dict(method=settings.method, substeps=settings.substeps)
    write_table(trials_frame(rows, trial_columns(settings.points[0])), out / "trials.csv")
    summary = summarize(settings, rows)
    write_table(summary_frame(summary, numerics), out / "summary.csv")
    x = x or default_x(list(settings.points))
    figure = plot_summary(summary, out / f"{x or 'conditions'}.png", x=x) if rows else None
    run = read_run(out)
    if check is None:  # keep the check of an earlier call on this run, if any
        try:
            previous = read_json(out / "summary.json")
            if isinstance(previous, dict) and previous.get("key") == run["key"]:
                check = previous.get("numerics_check")
        except ResultsError:
            pass
    result = to_jsonable(
        dict(
            kind="sweep",
            format=RUN_FORMAT,
            settings=run["settings"],
            key=run["key"],
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
    atomic_write_json(out / "summary.json", result)
    return result


def run_sweep(
    settings: SweepSettings,
    out,
    *,
    batch_size: int = 64,
    chunk_seconds: float = 5.0,
    check: int = 0,
    x: str | None = None,
    progress: Callable[[dict], None] | None = None,
    stop_after_batches: int | None = None,
    warn: Callable[[str], None] = warn_stderr,
    on_start: Callable[[int, int], None] | None = None,
) -> dict:
    """Run a sweep in folder ``out`` (created if needed) and write its tables and figure.

    Holds ``out``'s ``RunLock`` throughout; a folder holding a sweep with other settings
    is refused (one line naming the differences); trials with a valid record are reused,
    others (missing, truncated, altered, foreign: named in a warning) are computed.
    ``check`` > 0 re-runs that many trials per static group at 4x the substeps and puts
    the observed maximum relative ``phi_T`` error into ``summary.json``. Returns the
    ``summary.json`` contents plus ``computed`` (ids of the trials run now). ``on_start``
    is called as ``on_start(trials_on_disk, trials_to_run)`` once the folder is checked,
    before any computation (by process 0 only, in a ``jax.distributed`` job).
    """
    settings.validate()
    if x is not None and x not in POINT_DEFAULTS:
        raise ValueError(f"cannot plot against {x!r}: not a setting; known: {', '.join(POINT_DEFAULTS)}")
    if batch_size < 1:
        raise ValueError(f"batch_size must be >= 1, got {batch_size}")
    out = pathlib.Path(out)
    if check > 0 and distributed.is_distributed():
        raise ValueError("check re-runs trials on one process: run it without the distributed options")
    # In a jax.distributed job only process 0 touches the folder; every process gets its
    # list of trials to run, so all run the same batches in the same order.
    trials = _trials(settings, out)
    with open_run(run_folder(out), settings.run_settings(), trials, describe=_describe, warn=warn) as (done, todo):
        if on_start is not None and distributed.is_writer():
            on_start(len(done), len(todo))
        computed = compute(
            settings,
            out,
            todo,
            batch_size=batch_size,
            chunk_seconds=chunk_seconds,
            progress=progress,
            stop_after_batches=stop_after_batches,
        )
        if not distributed.is_writer():
            return dict(computed=computed)
        report = None
        if check > 0:
            rows, _ = collect(settings, out, warn=lambda _: None)
            report = numerics_check(settings, rows, check) if rows else None
        result = write_outputs(settings, out, check=report, x=x, warn=lambda _: None)
    return result | dict(computed=computed)
