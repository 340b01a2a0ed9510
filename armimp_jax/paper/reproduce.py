"""Run the paper reproduction: a specification of the study engine, and its aggregation.

A run folder holds one run (``study.runs.engine``, ``study.runs.runfolder``, ``docs/results.md``):

- ``run.json``: the run's settings (``ReproSettings``, the condition set included, and the
  package version), their key, the library versions and the accumulated wall time
  (``wall_s``: simulation, aggregation and figures of every session; ``record_wall_time``).
- ``trials/<id>.npz``: one checked record per finished trial (``armimp_jax.study.runs.results``): the
  estimate's arrays, the trial's metrics (``study.sweep.metrics.trial_metrics``), and the settings
  that fix its numbers (``trial_settings``: record length, substeps, Welch, base seed,
  condition, seed, and ``mhat`` for IMBIC) with their key.
- ``results.json`` / ``results.npz``: the aggregate, from which the report and figures are
  drawn (``load_results`` checks that the two belong together).
- ``conditions.csv``, ``claims.csv``, ``fits.csv`` (and ``.parquet``): the aggregate's tidy
  tables (``paper.tables``), also as pandas DataFrames from ``load_tables``.

``ReproSettings`` is a specification of the study engine: ``engine.run(settings, out)``
runs every trial whose record is missing or fails its check (the folder's lock, a run with
other settings refused, batches grouped by controller and acquisition, every record
written as soon as its batch finishes, so an interrupted run keeps every finished batch);
``reproduce`` does that and then, under the same lock, aggregates, draws and writes the
report (``finish``).

Seeds (``study.runs.seeds``): trial seed ``s`` draws its perturbation from
``fold_in(PRNGKey(base_seed), s)`` (attempt ``a > 0``, if input coherence is capped, from
that key folded with ``a``); every condition sees the same
signal shape for the same seed (common random numbers), scaled to its level's peak.
Diverged trials are saved and counted, and left out of every mean and claim.

Fits: ``aggregate`` adds each trial's fitted ``M, B, K`` (``claims.fit_metrics``, from its
stored ``f`` and ``Z``) to its metrics, so the records stay as written.

Many processes (``armimp_jax.study.runs.distributed``, ``docs/cluster.md``): process 0 holds the
lock and reads the folder and sends its list of trials to run to every process; every
process computes its shards of every batch, and only process 0 writes.
"""

from __future__ import annotations

import dataclasses
import pathlib
import platform
import time
from collections.abc import Callable

import jax
import numpy as np
import pandas as pd

from .._estimation.estimate import input_coherence
from .._estimation.welch import Welch
from .._simulate import stack_trials
from .._solver.numerics import PAPER_NUMERICS, Numerics
from ..presets import arm, perturbation_peak
from ..study.runs import engine
from ..study.runs.console import Console
from ..study.runs.results import (
    ResultsError,
    atomic_write_json,
    describe_difference,
    load_record,
    package_version,
    read_json,
    save_record,
    settings_key,
    stamped,
    to_jsonable,
)
from ..study.runs.runfolder import StudyRun, warn_stderr
from ..study.schema.points import Point
from ..study.sweep.metrics import ESTIMATE_FIELDS, estimate_arrays, trial_metrics
from ..study.sweep.tables import write_table
from .claims import (
    Condition,
    condition_summary,
    evaluate_claims,
    fit_metrics,
    paper_conditions,
    seed_summaries,
    trial_id,
    true_matrices,
)
from .tables import result_tables

DEFAULT_SEEDS = 3  # seeds per condition: the README's main command within ~3 minutes on 2 cores
LEVELS = dict(location=(1, 2, 3, 4), friction=(0, 1, 2), perturbation=(1, 2, 3))


@dataclasses.dataclass(frozen=True)
class ReproSettings(engine.SimulationSpec):
    """Everything that fixes the numbers of a reproduction run, the condition set included.

    Record length ``seconds`` [s], RK4 ``substeps`` per 1 ms period, Welch segment and
    overlap [samples] and ``fmax`` [Hz], ``seeds`` per condition from ``base_seed``, the
    interval-mean ``ablation``, ``max_input_coherence`` (redraw a seed's perturbation until
    below it; ``None``: never), IMBIC's ``mhat`` [kg] (times the identity), and the
    experiments' ``locations``, ``frictions`` and ``perturbations`` levels (stored sorted,
    without repeats). A specification of the study engine (``study.runs.engine.Spec``): a trial
    is ``(Condition, seed)``.
    """

    KIND = "reproduction"
    FORMAT = 2  # run.json layout (1: settings without a key, trials as .json/.npz pairs)
    NOUN = "run"

    seconds: float = 50.0
    substeps: int = 100
    nperseg: int = 8192
    noverlap: int = 6144
    fmax: float = 15.0
    seeds: int = DEFAULT_SEEDS
    base_seed: int = 0
    ablation: bool = True
    max_input_coherence: float | None = None
    mhat: float = 0.25
    locations: tuple[int, ...] = LEVELS["location"]
    frictions: tuple[int, ...] = LEVELS["friction"]
    perturbations: tuple[int, ...] = LEVELS["perturbation"]

    def __post_init__(self):
        # one spelling per setting, so that equal settings compare (and hash) equal
        for name in ("locations", "frictions", "perturbations"):
            object.__setattr__(self, name, tuple(sorted({int(v) for v in getattr(self, name)})))
        for name in ("seconds", "fmax", "mhat"):
            object.__setattr__(self, name, float(getattr(self, name)))
        if self.max_input_coherence is not None:
            object.__setattr__(self, "max_input_coherence", float(self.max_input_coherence))
        object.__setattr__(self, "ablation", bool(self.ablation))

    @property
    def n_samples(self) -> int:
        return int(round(self.seconds * 1000))

    @property
    def welch(self) -> Welch:
        return Welch(self.nperseg, self.noverlap, self.fmax)

    @property
    def numerics(self) -> Numerics:
        return dataclasses.replace(PAPER_NUMERICS, substeps=self.substeps)  # the paper's RK4, whatever Numerics() is

    @property
    def conditions(self) -> list[Condition]:
        return paper_conditions(
            ablation=self.ablation, locations=self.locations, frictions=self.frictions, perturbations=self.perturbations
        )

    def validate(self) -> None:
        """Raise ``ValueError`` (one line) for settings that cannot run."""
        for name, allowed in LEVELS.items():
            values = getattr(self, name + "s")
            bad = [v for v in values if v not in allowed]
            if bad or not values:
                raise ValueError(f"unknown {name} level(s) {bad}; allowed: {', '.join(map(str, allowed))}")
        if self.seeds < 1:
            raise ValueError(f"seeds must be >= 1, got {self.seeds}")
        if self.substeps < 1 or int(self.substeps) != self.substeps:
            raise ValueError(f"substeps must be an integer >= 1, got {self.substeps}")
        if not self.mhat > 0:
            raise ValueError(f"mhat must be > 0 kg, got {self.mhat}")
        if not self.seconds > 0:
            raise ValueError(f"seconds must be > 0, got {self.seconds}")
        if self.max_input_coherence is not None and not 0 < self.max_input_coherence <= 1:
            raise ValueError(f"max_input_coherence must be in (0, 1], got {self.max_input_coherence}")
        try:
            self.welch.check(self.n_samples)
        except ValueError as err:
            raise ValueError(f"--seconds {self.seconds:g}: {err}") from None

    def run_settings(self) -> dict:
        """The run's settings as saved in ``run.json`` (package version included)."""
        return stamped(dataclasses.asdict(self))

    @classmethod
    def from_saved(cls, saved: dict, *, where: str = "run.json") -> ReproSettings:
        """Settings from ``run_settings()`` output (the package version entry is dropped)."""
        names = {f.name for f in dataclasses.fields(cls)}
        missing = names - saved.keys()
        if missing:
            raise ResultsError(f"{where}: settings lack {', '.join(sorted(missing))} (written by another armimp_jax?)")
        return cls(**{k: v for k, v in saved.items() if k in names})

    def trial_settings(self, cond: Condition, seed: int) -> dict:
        """Every value that changes the numbers of one trial (and nothing else: the seed
        count, the condition set and the batch size do not; ``mhat`` only for IMBIC)."""
        out = dict(
            condition=dataclasses.asdict(cond),
            seed=int(seed),
            base_seed=self.base_seed,
            seconds=self.seconds,
            numerics=self.numerics.settings(),
            welch=self.welch._asdict(),
            max_input_coherence=self.max_input_coherence,
        )
        if cond.controller == "imbic":
            out["mhat"] = self.mhat
        return stamped(out)

    # --- the engine's specification ---

    describe = staticmethod(describe_difference)

    def run_extra(self) -> dict:
        """What ``run.json`` adds: the library versions and the wall time so far [s]."""
        return dict(versions=versions(), wall_s=0.0)

    def trials(self) -> list[tuple[Condition, int]]:
        return [(c, s) for c in self.conditions for s in range(self.seeds)]

    def trial_record(self, t: tuple[Condition, int]) -> tuple[str, dict]:
        return trial_id(*t), self.trial_settings(*t)

    def group(self, t: tuple[Condition, int]) -> tuple:
        return t[0].controller, t[0].acquisition

    def samples(self, t: tuple[Condition, int]) -> int:
        return self.n_samples

    def build(self, batch, signals: engine.Perturbations) -> engine.Simulation:
        """The trials of a batch of ``(Condition, seed)`` (each condition's point, ``Condition.point``)
        and their perturbations (``draw_perturbations``), on the paper's RK4, assessed with the
        run's Welch settings."""
        params = stack_trials([self.point(c).trial for c, _ in batch])
        f_delta = np.stack([self.draw(s, signals)[0][c.perturbation] for c, s in batch])
        return engine.Simulation(params, f_delta, self.numerics, welch=self.welch)

    def measure(self, batch, built, sim, outcome) -> list[tuple[dict, dict]]:
        """Per trial ``(arrays, meta)``: the estimate's arrays, and its metrics
        (``study.sweep.metrics.trial_metrics``) with the condition, seed and perturbation draw."""
        signals = built.signals
        out = []
        for i, (c, s) in enumerate(batch):
            est = estimate_arrays(outcome.estimate, i)
            meta = dict(
                id=trial_id(c, s),
                condition=dataclasses.asdict(c),
                seed=s,
                perturbation_attempt=self.draw(s, signals)[2],
                input_coherence_max=self.draw(s, signals)[1],
                diverged=bool(sim.diverged[i]),
                diverged_at=int(sim.diverged_at[i]),
                batch_wall_s=None,  # the engine's (placed here: the records' field order)
                batch_size=None,
                metrics=trial_metrics(est["f"], est["Z"], est, arm(c.location)),
            )
            out.append((est, meta))
        return out

    def point(self, cond: Condition) -> Point:
        """The point (``study.Point``) of a condition at this run's settings."""
        return cond.point(mhat=self.mhat, seconds=self.seconds, welch=self.welch)

    def draw(self, seed: int, signals: engine.Perturbations) -> tuple:
        """``draw_perturbations`` of ``seed`` over the run's levels, drawn once per run."""
        levels = sorted({c.perturbation for c in self.conditions})  # IMBIC runs at level 1 whatever PD's
        return signals.keep(("levels", seed), lambda: draw_perturbations(self, seed, levels, signals))


QUICK = ReproSettings(seconds=6.0, substeps=10, nperseg=1024, noverlap=768)


def draw_perturbations(
    settings: ReproSettings, seed: int, levels, signals: engine.Perturbations | None = None
) -> tuple[dict, float, int]:
    """Perturbations of one seed for each level, the input coherence and the attempt used
    (``study.runs.seeds``: attempt ``a > 0`` redraws from the seed's key folded with ``a``), from
    ``signals`` (a run's cache; default a new one)."""
    w = settings.welch
    signals = engine.Perturbations(settings.base_seed) if signals is None else signals
    for attempt in range(100):
        sig = {lv: signals(seed, settings.n_samples, perturbation_peak(lv), redraw=attempt) for lv in levels}
        coh = float(input_coherence(sig[levels[0]], fs=w.fs, nperseg=w.nperseg, noverlap=w.noverlap, fmax=w.fmax))
        if settings.max_input_coherence is None or coh < settings.max_input_coherence:
            return sig, coh, attempt
    raise RuntimeError(
        f"seed {seed}: no perturbation with input coherence < {settings.max_input_coherence} in 100 draws"
    )


def versions() -> dict:
    import jaxlib
    import matplotlib
    import scipy

    return dict(
        armimp_jax=package_version(),
        jax=jax.__version__,
        jaxlib=jaxlib.__version__,
        numpy=np.__version__,
        scipy=scipy.__version__,
        pandas=pd.__version__,
        matplotlib=matplotlib.__version__,
        python=platform.python_version(),
        backend=jax.default_backend(),
        devices=jax.device_count(),
    )


def trial_path(out, cond: Condition, seed: int) -> pathlib.Path:
    """Where the record of trial ``(cond, seed)`` lives in run folder ``out``."""
    return StudyRun.of(ReproSettings, out).record_path(trial_id(cond, seed))


def _study(out) -> StudyRun:
    return out if isinstance(out, StudyRun) else StudyRun.of(ReproSettings, out)


def load_trials(
    out, settings: ReproSettings, *, warn: Callable[[str], None] = warn_stderr
) -> tuple[list[dict], dict, list[str]]:
    """The run's trials that pass their check: metadata list, ``{id: arrays}``, and the ids
    of the trials that are missing or failed (the latter named in a warning)."""
    records, missing = engine.records(settings, _study(out), warn=warn, note="left out")
    metas = [rec.meta for rec in records.values()]
    arrays = {rec.meta["id"]: rec.arrays for rec in records.values()}
    return metas, arrays, [trial_id(c, s) for c, s in missing]


def add_fits(metas: list[dict], arrays: dict) -> None:
    """Add the fitted ``M, B, K`` of each trial (``claims.fit_metrics``, from its stored ``f``
    and ``Z``) to its ``metrics``, in place. Done when aggregating, so that every record gets
    the same fit, and the records stay as they were written."""
    groups: dict[tuple, list] = {}
    for m in metas:
        groups.setdefault((np.asarray(arrays[m["id"]]["f"]).tobytes(), m["condition"]["acquisition"]), []).append(m)
    for (_, acquisition), group in groups.items():
        z, locs = np.stack([arrays[m["id"]]["Z"] for m in group]), [m["condition"]["location"] for m in group]
        fits = fit_metrics(arrays[group[0]["id"]]["f"], z, locs, acquisition=acquisition)
        for m, fit in zip(group, fits):
            m["metrics"] = m["metrics"] | fit


def aggregate(out, *, warn: Callable[[str], None] = warn_stderr) -> tuple[dict, dict]:
    """Write ``results.json`` and ``results.npz`` from the valid trial records of the run in
    ``out`` (a ``StudyRun`` or a folder), and the tables ``conditions.csv``, ``claims.csv``
    and ``fits.csv`` (``result_tables``; also as ``.parquet`` when ``pyarrow`` is
    importable); return the results dict and the per-trial arrays (as ``load_results``
    would read them back).

    ``complete`` is true when every trial of the run's condition set and seeds is there;
    ``diverged`` lists the trials left out of the means and claims.
    """
    study = _study(out)
    out = study.path
    with study.lock():
        run = study.read()
        settings = ReproSettings.from_saved(run["settings"], where=str(study.run_file))
        metas, arrays, missing = load_trials(study, settings, warn=warn)
        add_fits(metas, arrays)
        summary = condition_summary(metas)
        claims = [dataclasses.asdict(c) for c in evaluate_claims(summary, seed_summaries(metas))]
        results = to_jsonable(  # as load_results reads it back: NaN -> None
            dict(
                format=ReproSettings.FORMAT,
                complete=not missing,
                settings=run["settings"],
                key=run["key"],
                versions=run["versions"],
                trials_expected=len(settings.conditions) * settings.seeds,
                missing=missing,
                diverged=[m["id"] for m in metas if m["diverged"]],
                trials=metas,
                conditions=[
                    dict(condition=dataclasses.asdict(c), truth=true_matrices(c.location), **m)
                    for c, m in summary.items()
                ],
                claims=claims,
                wall_s=run.get("wall_s"),
            )
        )
        atomic_write_json(out / "results.json", results)
        ids = [m["id"] for m in metas]
        stacked = {"trial_ids": np.array(ids, dtype=str)}
        if ids:
            stacked |= {name: np.stack([arrays[i][name] for i in ids]) for name in ESTIMATE_FIELDS}
        save_record(out / "results.npz", settings=run["settings"], arrays=stacked)
        for name, frame in result_tables(results).items():
            write_table(frame, out / f"{name}.csv")
    return results, arrays


def load_results(out) -> tuple[dict, dict]:
    """``results.json`` and the per-trial arrays from ``results.npz`` (for ``--replot``),
    checked to belong to each other and to the run's settings."""
    if not out.is_dir():
        raise ResultsError(f"{out}: no such folder")
    results = read_json(out / "results.json")
    if not isinstance(results, dict) or results.get("format") != ReproSettings.FORMAT:
        raise ResultsError(f"{out / 'results.json'}: written by an older armimp_jax: rerun the reproduction")
    if settings_key(results["settings"]) != results["key"]:
        raise ResultsError(f"{out / 'results.json'}: its settings were edited (key mismatch)")
    rec = load_record(out / "results.npz", settings=results["settings"])
    ids = [str(i) for i in rec.arrays["trial_ids"]]
    if ids != [t["id"] for t in results["trials"]]:
        raise ResultsError(f"{out / 'results.npz'}: holds other trials than results.json")
    arrays = {tid: {k: rec.arrays[k][j] for k in ESTIMATE_FIELDS if k in rec.arrays} for j, tid in enumerate(ids)}
    return results, arrays


def record_wall_time(out, results: dict, seconds: float) -> dict:
    """Add ``seconds`` (a session's whole work: simulation, aggregation, figures) to the run's
    ``wall_s`` in ``run.json`` and put the total into ``results`` and ``results.json`` (what
    the report prints); returns ``results``."""
    study = _study(out)
    with study.lock():
        results["wall_s"] = study.add_wall_time(seconds)
        atomic_write_json(study.path / "results.json", results)
    return results


def load_tables(out) -> dict[str, pd.DataFrame]:
    """The tidy tables (``paper.tables.result_tables``) of the aggregated run in folder ``out``,
    from its checked ``results.json`` and ``results.npz`` (``load_results``)."""
    return result_tables(load_results(pathlib.Path(out))[0])


# --- the whole reproduction -----------------------------------------------------------------


def reproduce(
    settings: ReproSettings,
    out,
    *,
    resume: bool = False,
    batch_size: int = 48,
    console: Console | None = None,
    warn: Callable[[str], None] = warn_stderr,
    started: float | None = None,
) -> engine.Outcome:
    """The reproduction end to end, on the study engine: ``engine.run`` (only the trials
    without a valid record; Ctrl-C keeps every finished batch), then, with the folder still
    locked, ``aggregate``, the figures (``plots.all_figures``), the wall time (everything
    since ``started``, a ``time.perf_counter()``, or since this call) and ``REPORT.md``.
    ``Outcome.finished`` is ``(results, report path)`` (in the writing process; an
    interrupted run gets a partial report). ``console`` says what happens (default quiet)."""
    from . import plots, report

    started = time.perf_counter() if started is None else started
    console = Console(quiet=True) if console is None else console

    def header(on_disk: int, to_run: int) -> str:
        return (
            f"{len(settings.conditions)} conditions x {settings.seeds} seed(s), {settings.seconds:g} s records, "
            f"{settings.substeps} substeps -> {out} ({on_disk} trials on disk, {to_run} to run)"
        )

    def finish(run: StudyRun, outcome: engine.Outcome):
        console.end(len(outcome.computed))
        # the folder's scan named every record that failed its check
        results, arrays = console.step("aggregating", lambda: aggregate(run, warn=lambda _: None))
        figures = console.step("plotting", lambda: plots.all_figures(results, arrays, run.path))
        record_wall_time(run, results, time.perf_counter() - started)
        path = console.step("writing the report", lambda: report.write_report(results, run.path, figures))
        return results, path

    return engine.run(
        settings,
        out,
        resume=resume,
        batch_size=batch_size,
        chunk_seconds=min(5.0, settings.seconds),
        progress=console.progress,
        on_start=console.starter(header),
        finish=finish,
        interruptible=True,
        warn=warn,
    )


def replot(out, *, console: Console | None = None) -> tuple[list, pathlib.Path]:
    """Redraw the figures and ``REPORT.md`` of the finished run in ``out`` from its saved
    results (``load_results``), under its lock; returns ``(figures, report path)``."""
    from . import plots, report

    console = Console(quiet=True) if console is None else console
    study = StudyRun.of(ReproSettings, out)
    with study.lock():
        results, arrays = load_results(study.path)
        figures = console.step("plotting", lambda: plots.all_figures(results, arrays, study.path))
        path = console.step("writing the report", lambda: report.write_report(results, study.path, figures))
    return figures, path
