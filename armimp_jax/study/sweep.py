"""General sweeps: a grid (or a list of points) over any settings of a trial, times seeds.

The points (``study.points``: ``POINT_DEFAULTS``, ``normalize_point``, ``expand``,
``read_toml``, ``parse_set``) and ``SweepSettings`` fix a run. ``SweepSettings`` is a
specification of the run-trials engine (``study.engine``): ``run_sweep`` runs every
``(point, seed)`` that has no valid record in the output folder (batched by static
structure, sharded over the devices, in chunks for progress), saves one checked record
per trial (``study.results``), then writes the tidy table ``trials.csv`` (one row per
trial, ``trial_row``), ``summary.csv``/``summary.json`` (per point over seeds: mean,
standard deviation, 95% t-interval, count of diverged trials, which are left out of
every statistic; ``study.stats``) and a figure of ``phi_T`` against the swept quantity
(``study.figures``). ``docs/sweeps.md`` describes the files. ``load_sweep`` and
``load_summary`` give the tables as pandas DataFrames from the checked records.

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
from collections.abc import Callable, Mapping

import jax
import numpy as np
import pandas as pd

from .._batch import assess_batch, check_numerics, simulate_batch
from .._estimation.fit import fit_impedance
from .._simulate import stack_trials
from .._solver.numerics import SWEEP_NUMERICS, Numerics, named_solver
from . import distributed, engine
from .figures import plot_summary
from .metrics import estimate_arrays
from .points import (
    build_trial,
    default_x,
    known_settings,
    n_samples,
    normalize_point,
    point_arm,
    point_columns,
    point_welch,
    static_group,
    swept_settings,
)
from .points import expand as expand  # sweeps/friction_threshold.py builds its points here
from .results import ResultsError, atomic_write_json, describe_difference, read_json, settings_key, stamped, to_jsonable
from .runfolder import warn_stderr
from .seeds import seed_perturbation, sensor_noise_key
from .stats import seed_stats
from .tables import ELEMENTS, METRIC_COLUMNS, summary_frame, trial_columns, trials_frame, write_table

# --- run settings ---------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class SweepSettings:
    """Everything that fixes a sweep's numbers: its normalized ``points`` (``expand``), the
    number of ``seeds`` per point from ``base_seed``, and the integration ``method`` and
    ``substeps`` per 1 ms period (default ``SWEEP_NUMERICS``). A specification of the
    run-trials engine (``study.engine.Spec``): a trial is ``(point index, seed)``."""

    KIND = "sweep"
    FORMAT = 1  # layout of a sweep's run.json
    NOUN = "sweep"

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
            dict(points=list(self.points), seeds=self.seeds, base_seed=self.base_seed, numerics=self._numerics_dict())
        )

    def run_extra(self) -> dict:
        return {}

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
        return static_group(self.points[trial[0]])

    def samples(self, trial: tuple[int, int]) -> int:
        return n_samples(self.points[trial[0]])

    def compile_key(self, batch: list) -> tuple:
        """A batch's compiled shape: its group, size and whether it draws sensor noise."""
        return self.group(batch[0]), len(batch), any(_noisy(self.points[i]) for i, _ in batch)

    def batch_runner(self) -> Callable:
        signals = _Perturbations(self.base_seed)
        return functools.partial(run_batch, self, signals=signals)


def trial_id(point: Mapping, seed: int) -> str:
    """File name stem of a trial: a short hash of its point (stable across runs) and the seed."""
    return f"p{settings_key(dict(point=dict(point)))[:12]}-s{seed}"


def saved_settings(out) -> SweepSettings:
    """The settings of the sweep in ``out`` (to resume it)."""
    return engine.saved_settings(SweepSettings, out)


# --- per-trial metrics ------------------------------------------------------------------------


def _cells(prefix: str, a) -> dict:
    a = np.asarray(a, dtype=float).reshape(-1)
    return {f"{prefix}_{e}": float(v) for e, v in zip(ELEMENTS, a, strict=True)}


def trial_row(point: Mapping, outcome_i: Mapping, fit_i: Mapping) -> dict:
    """The scalar columns of one trial's table row (``METRIC_COLUMNS`` plus ``diverged``, ``diverged_at``).

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


def run_batch(settings: SweepSettings, batch, *, signals: _Perturbations, mesh, chunk_samples: int, progress=None):
    """Simulate and assess one batch of ``(point index, seed)`` sharing a ``static_group``;
    returns per trial ``(arrays, meta)``: the estimate's arrays with the fit, and the
    record's meta (id, point index, seed, the ``trial_row`` metrics)."""
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
        chunk_samples=chunk_samples,
        progress=progress,
    )
    outcome = assess_batch(params, f_delta, sim, point_welch(points[0]), mesh=mesh)
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
        meta = dict(id=trial_id(point, s), point_index=i, seed=s, metrics=trial_row(point, out_j, fit_j))
        out.append((est | {f"fit_{k}": v for k, v in fit_j.items()}, meta))
    return out


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
    records, missing = engine.trial_status(settings, out, warn=warn)
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
    write_table(trials_frame(rows, trial_columns(settings.points)), out / "trials.csv")
    summary = summarize(settings, rows)
    write_table(summary_frame(summary, numerics), out / "summary.csv")
    x = x or default_x(list(settings.points))
    figure = plot_summary(summary, out / f"{x or 'conditions'}.png", x=x) if rows else None
    run = engine.run_folder(settings, out).read()
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
            format=settings.FORMAT,
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
    if x is not None and x not in known_settings():
        raise ValueError(f"cannot plot against {x!r}: not a setting; known: {', '.join(known_settings())}")
    if batch_size < 1:
        raise ValueError(f"batch_size must be >= 1, got {batch_size}")
    out = pathlib.Path(out)
    if check > 0 and distributed.is_distributed():
        raise ValueError("check re-runs trials on one process: run it without the distributed options")
    # In a jax.distributed job only process 0 touches the folder; every process gets its
    # list of trials to run, so all run the same batches in the same order.
    with engine.open_study(settings, out, warn=warn) as (done, todo):
        if on_start is not None and distributed.is_writer():
            on_start(len(done), len(todo))
        computed = engine.run_trials(
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
