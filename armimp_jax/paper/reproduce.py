"""Run the paper reproduction: a specification of the study engine, and its aggregation.

A run folder holds one run (``study.engine``, ``study.runfolder``, ``docs/results.md``):

- ``run.json``: the run's settings (``ReproSettings``, the condition set included, and the
  package version), their key, the library versions and the accumulated wall time
  (``wall_s``: simulation, aggregation and figures of every session; ``record_wall_time``).
- ``trials/<id>.npz``: one checked record per finished trial (``armimp_jax.study.results``): the
  estimate's arrays, the trial's metrics (``study.metrics.trial_metrics``), and the settings
  that fix its numbers (``trial_settings``: record length, substeps, Welch, base seed,
  condition, seed, and ``mhat`` for IMBIC) with their key.
- ``results.json`` / ``results.npz``: the aggregate, from which the report and figures are
  drawn (``load_results`` checks that the two belong together).
- ``conditions.csv``, ``claims.csv``, ``fits.csv`` (and ``.parquet``): the aggregate's tidy
  tables (``paper.tables``), also as pandas DataFrames from ``load_tables``.

``run_reproduction`` runs every trial whose record is missing or fails its check on the
study engine (``study.engine.open_study`` and ``run_trials``: the folder's lock, a run with
other settings refused, batches grouped by controller and acquisition, every record
written as soon as its batch finishes, so an interrupted run keeps every finished batch).

Seeds (``study.seeds``): trial seed ``s`` draws its perturbation from
``fold_in(PRNGKey(base_seed), s)`` (attempt ``a > 0``, if input coherence is capped, from
that key folded with ``a``); every condition sees the same
signal shape for the same seed (common random numbers), scaled to its level's peak.
Diverged trials are saved and counted, and left out of every mean and claim.

Fits: ``aggregate`` adds each trial's fitted ``M, B, K`` (``claims.fit_metrics``, from its
stored ``f`` and ``Z``) to its metrics, so the records stay as written.

Many processes (``armimp_jax.study.distributed``, ``docs/cluster.md``): process 0 holds the
lock and reads the folder and sends its list of trials to run to every process; every
process computes its shards of every batch, and only process 0 writes.
"""

from __future__ import annotations

import dataclasses
import pathlib
import platform
from collections.abc import Callable

import jax
import numpy as np
import pandas as pd

from .._batch import assess_batch, simulate_batch
from .._estimation.estimate import input_coherence
from .._estimation.welch import Welch
from .._simulate import stack_trials
from .._solver.numerics import PAPER_NUMERICS, Numerics
from ..presets import arm, perturbation_peak, trial
from ..study import engine
from ..study.metrics import ESTIMATE_FIELDS, estimate_arrays, trial_metrics
from ..study.results import (
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
from ..study.runfolder import warn_stderr
from ..study.seeds import seed_perturbation
from ..study.tables import write_table
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
class ReproSettings:
    """Everything that fixes the numbers of a reproduction run, the condition set included.

    Record length ``seconds`` [s], RK4 ``substeps`` per 1 ms period, Welch segment and
    overlap [samples] and ``fmax`` [Hz], ``seeds`` per condition from ``base_seed``, the
    interval-mean ``ablation``, ``max_input_coherence`` (redraw a seed's perturbation until
    below it; ``None``: never), IMBIC's ``mhat`` [kg] (times the identity), and the
    experiments' ``locations``, ``frictions`` and ``perturbations`` levels (stored sorted,
    without repeats). A specification of the study engine (``study.engine.Spec``): a trial
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

    def batch_runner(self) -> Callable:
        return _BatchRunner(self)


QUICK = ReproSettings(seconds=6.0, substeps=10, nperseg=1024, noverlap=768)


def draw_perturbations(settings: ReproSettings, seed: int, levels) -> tuple[dict, float, int]:
    """Perturbations of one seed for each level, the input coherence and the attempt used
    (``study.seeds``: attempt ``a > 0`` redraws from the seed's key folded with ``a``)."""
    w = settings.welch
    for attempt in range(100):
        sig = {
            lv: seed_perturbation(settings.base_seed, seed, settings.n_samples, perturbation_peak(lv), redraw=attempt)
            for lv in levels
        }
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
    return engine.record_path(out, trial_id(cond, seed))


class _BatchRunner:
    """Runs batches of ``(Condition, seed)`` for the engine; draws each seed's perturbations
    once per run."""

    def __init__(self, settings: ReproSettings):
        self.settings = settings
        self.levels = sorted({c.perturbation for c in settings.conditions})  # IMBIC runs at level 1 whatever PD's
        self.cache: dict[int, tuple] = {}

    def signals(self, seed: int) -> tuple:
        if seed not in self.cache:
            self.cache[seed] = draw_perturbations(self.settings, seed, self.levels)
        return self.cache[seed]

    def __call__(self, batch, *, mesh, chunk_samples: int, progress=None) -> list[tuple[dict, dict]]:
        st = self.settings
        mhat = st.mhat * np.eye(2)
        params = stack_trials(
            [trial(c.controller, c.friction, c.location, mhat=mhat, acquisition=c.acquisition) for c, _ in batch]
        )
        f_delta = np.stack([self.signals(s)[0][c.perturbation] for c, s in batch])
        sim = simulate_batch(
            params, f_delta, numerics=st.numerics, mesh=mesh, chunk_samples=chunk_samples, progress=progress
        )
        outcome = assess_batch(params, f_delta, sim, st.welch, mesh=mesh)
        out = []
        for i, (c, s) in enumerate(batch):
            est = estimate_arrays(outcome.estimate, i)
            _, coh, attempt = self.signals(s)
            meta = dict(
                id=trial_id(c, s),
                condition=dataclasses.asdict(c),
                seed=s,
                perturbation_attempt=attempt,
                input_coherence_max=coh,
                diverged=bool(sim.diverged[i]),
                diverged_at=int(sim.diverged_at[i]),
                batch_wall_s=None,  # the engine's (placed here: the records' field order)
                batch_size=None,
                metrics=trial_metrics(est["f"], est["Z"], est, arm(c.location)),
            )
            out.append((est, meta))
        return out


def run_reproduction(
    settings: ReproSettings,
    out,
    *,
    batch_size: int = 48,
    chunk_seconds: float = 5.0,
    progress: Callable[[dict], None] | None = None,
    stop_after_batches: int | None = None,
    warn: Callable[[str], None] = warn_stderr,
) -> list[str]:
    """Simulate, estimate and score every trial of ``settings`` that has no valid record in
    ``out``; returns the ids computed now.

    Runs on the study engine (``study.engine.open_study``: the writer holds ``out``'s
    ``RunLock`` throughout, a folder holding another run is refused; ``run_trials``).
    ``progress`` receives the engine's dict (``done``/``total`` trial samples,
    ``trials_done``, ``trials_total``, ``elapsed_s``, ``eta_s``) after every chunk.
    ``stop_after_batches`` stops early (used to test resuming). ``warn`` receives one line
    per trial record that failed its check.

    In a ``jax.distributed`` job (``armimp_jax.study.distributed``) call it in every process with
    the same arguments: each process computes its shards of every batch, and only process
    0 writes the trial records.
    """
    with engine.open_study(settings, out, warn=warn) as (_, todo):
        return engine.run_trials(
            settings,
            out,
            todo,
            batch_size=batch_size,
            chunk_seconds=chunk_seconds,
            progress=progress,
            stop_after_batches=stop_after_batches,
        )


def load_trials(
    out, settings: ReproSettings, *, warn: Callable[[str], None] = warn_stderr
) -> tuple[list[dict], dict, list[str]]:
    """The run's trials that pass their check: metadata list, ``{id: arrays}``, and the ids
    of the trials that are missing or failed (the latter named in a warning)."""
    records, missing = engine.trial_status(settings, out, warn=warn, note="left out")
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
    """Write ``results.json`` and ``results.npz`` from the run's valid trial records, and the
    tables ``conditions.csv``, ``claims.csv`` and ``fits.csv`` (``result_tables``; also as
    ``.parquet`` when ``pyarrow`` is importable); return the results dict and the per-trial
    arrays (as ``load_results`` would read them back).

    ``complete`` is true when every trial of the run's condition set and seeds is there;
    ``diverged`` lists the trials left out of the means and claims.
    """
    folder = engine.run_folder(ReproSettings, out)
    with folder.lock():
        run = folder.read()
        settings = ReproSettings.from_saved(run["settings"], where=str(folder.run_file))
        metas, arrays, missing = load_trials(out, settings, warn=warn)
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
    out = pathlib.Path(out)
    folder = engine.run_folder(ReproSettings, out)
    with folder.lock():
        results["wall_s"] = engine.add_wall_time(ReproSettings, out, seconds)
        atomic_write_json(out / "results.json", results)
    return results


def load_tables(out) -> dict[str, pd.DataFrame]:
    """The tidy tables (``paper.tables.result_tables``) of the aggregated run in folder ``out``,
    from its checked ``results.json`` and ``results.npz`` (``load_results``)."""
    return result_tables(load_results(pathlib.Path(out))[0])
