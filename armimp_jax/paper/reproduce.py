"""Run the paper reproduction: batched trials, checked per-trial records, resume, aggregation.

A run folder holds one run (``study.runfolder``, ``docs/results.md``):

- ``run.json``: the run's settings (``ReproSettings``, the condition set included, and the
  package version), their key, the library versions and the accumulated wall time.
- ``trials/<id>.npz``: one checked record per finished trial (``armimp_jax.study.results``): the
  estimate's arrays, the trial's metrics, and the settings that fix its numbers
  (``trial_settings``: record length, substeps, Welch, base seed, condition, seed, and
  ``mhat`` for IMBIC) with their key.
- ``results.json`` / ``results.npz``: the aggregate, from which the report and figures are
  drawn (``load_results`` checks that the two belong together).
- ``conditions.csv``, ``claims.csv``, ``fits.csv`` (and ``.parquet``): the aggregate's tidy
  tables, also as pandas DataFrames from ``load_tables`` (``conditions_frame``,
  ``claims_frame``, ``fits_frame``).

``run_reproduction`` refuses a folder that holds a run with other settings, takes the
folder's lock (``RunLock``) for as long as it runs, and simulates every trial whose record
is missing or fails its check (truncated, altered, or made with other settings: named in
a warning and recomputed), in vmapped, sharded batches grouped by the static settings
(controller, acquisition). It writes each trial as soon as its batch finishes, atomically,
so an interrupted run keeps every finished batch and a later call computes only the rest.

Seeds (``study.seeds``): trial seed ``s`` draws its perturbation from
``fold_in(PRNGKey(base_seed), s)`` (attempt ``a > 0``, if input coherence is capped, from
that key folded with ``a``); every condition sees the same
signal shape for the same seed (common random numbers), scaled to its level's peak.
Diverged trials are saved and counted, and left out of every mean and claim.

Fits: ``aggregate`` adds each trial's fitted ``M, B, K`` (``claims.fit_metrics``, from its
stored ``f`` and ``Z``) to its metrics, so the records stay as written.

Many processes (``armimp_jax.study.distributed``, ``docs/cluster.md``): ``open_run`` lets process 0
hold the lock and read the folder and sends its list of trials to run to every process;
every process computes its shards of every batch, and only process 0 writes.
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

from .._batch import assess_batch, make_mesh, simulate_batch
from .._estimation.welch import Welch, input_coherence
from .._simulate import stack_trials
from .._solver.numerics import PAPER_NUMERICS, Numerics
from ..presets import perturbation_peak, trial
from ..study import distributed
from ..study.results import (
    ResultsError,
    atomic_write_json,
    load_record,
    package_version,
    read_json,
    save_record,
    settings_key,
    stamped,
    to_jsonable,
)
from ..study.runfolder import RunFolder, warn_stderr
from ..study.runfolder import open_run as _open_run
from ..study.runfolder import trial_status as _record_status
from ..study.seeds import seed_perturbation
from ..study.tables import INTEGER, STRING, table, write_table
from .claims import (
    Condition,
    condition_summary,
    evaluate_claims,
    fit_metrics,
    paper_conditions,
    seed_summaries,
    trial_id,
    trial_metrics,
    true_matrices,
)

ESTIMATE_FIELDS = ("f", "Z", "coh_multiple_x", "coh_partial_x", "coh_multiple_fh", "coh_partial_fh", "coh_inputs")
DEFAULT_SEEDS = 3  # seeds per condition: the README's main command within ~3 minutes on 2 cores
RUN_KIND = "reproduction"
RUN_FORMAT = 2  # run.json layout (1: settings without a key, trials as .json/.npz pairs)
LEVELS = dict(location=(1, 2, 3, 4), friction=(0, 1, 2), perturbation=(1, 2, 3))


@dataclasses.dataclass(frozen=True)
class ReproSettings:
    """Everything that fixes the numbers of a reproduction run, the condition set included.

    Record length ``seconds`` [s], RK4 ``substeps`` per 1 ms period, Welch segment and
    overlap [samples] and ``fmax`` [Hz], ``seeds`` per condition from ``base_seed``, the
    interval-mean ``ablation``, ``max_input_coherence`` (redraw a seed's perturbation until
    below it; ``None``: never), IMBIC's ``mhat`` [kg] (times the identity), and the
    experiments' ``locations``, ``frictions`` and ``perturbations`` levels (stored sorted,
    without repeats).
    """

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


def trial_path(out, cond: Condition, seed: int):
    return out / "trials" / f"{trial_id(cond, seed)}.npz"


def run_folder(out) -> RunFolder:
    """The run folder ``out`` of a reproduction (``study.runfolder``)."""
    return RunFolder(out, kind=RUN_KIND, format=RUN_FORMAT, noun="run")


def read_run(out) -> dict:
    """``run.json`` of the run in ``out``, checked (``ResultsError`` naming what is wrong)."""
    return run_folder(out).read()


def saved_settings(out) -> ReproSettings:
    """The ``ReproSettings`` of the run in ``out`` (for resuming it)."""
    return ReproSettings.from_saved(read_run(out)["settings"], where=str(out / "run.json"))


def check_resume(out, saved: ReproSettings, wanted: ReproSettings) -> None:
    """Refuse (one line) options given with ``--resume out`` that change the run there."""
    run_folder(out).check_resume(saved.run_settings(), wanted.run_settings())


def prepare_output(out, settings: ReproSettings, *, resume: bool) -> None:
    """Make ``out`` ready for a run with ``settings``: create it, check it is writable, and
    write ``run.json`` (with the library versions and ``wall_s``) unless it is there.

    A folder that holds a run with other settings is refused with one line naming the
    differences (its trials would not match); so is ``resume`` on a folder with no run.
    """
    run_folder(out).prepare(settings.run_settings(), resume=resume, extra=dict(versions=versions(), wall_s=0.0))


def add_wall_time(out, seconds: float) -> None:
    """Add ``seconds`` of computing to the run's ``wall_s`` in ``run.json``."""
    folder = run_folder(out)
    folder.update(wall_s=(folder.read().get("wall_s") or 0.0) + seconds)


def _trials(settings: ReproSettings, out) -> list:
    """``((Condition, seed), record path, trial settings)`` of every trial, in run order."""
    return [
        ((c, s), trial_path(out, c, s), settings.trial_settings(c, s))
        for c in settings.conditions
        for s in range(settings.seeds)
    ]


def trial_status(settings: ReproSettings, out, *, warn: Callable[[str], None] = warn_stderr) -> tuple[list, list]:
    """``(done, todo)`` lists of ``(Condition, seed)``: a trial is done when its record
    passes its check under ``settings``; any other existing record is named in a warning."""
    records, todo = _record_status(_trials(settings, out), warn=warn)
    return list(records), todo


def open_run(settings: ReproSettings, out, *, resume: bool = False, warn: Callable[[str], None] = warn_stderr):
    """Context manager that starts (or resumes) the run of ``settings`` in ``out`` and yields
    ``(done, todo)`` lists of ``(Condition, seed)`` (``study.runfolder.open_run``).

    The writing process (``distributed.is_writer()``: process 0, or the only one) holds
    ``out``'s ``RunLock`` until the block ends and calls ``prepare_output`` (a folder holding
    another run is refused; so is ``resume`` on a folder with no run). In a
    ``jax.distributed`` job every process gets process 0's lists, so all run the same
    batches in the same order, and a refusal is raised in every process.
    """
    settings.validate()
    extra = dict(versions=versions(), wall_s=0.0)
    return _open_run(
        run_folder(out), settings.run_settings(), _trials(settings, out), resume=resume, extra=extra, warn=warn
    )


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

    Runs inside ``open_run`` (the writer holds ``out``'s ``RunLock`` throughout; a folder
    holding another run is refused). ``progress`` receives a dict (``done``/``total``
    substep counts, ``trials_done``, ``trials_total``, ``elapsed_s``, ``eta_s``) after
    every chunk. ``stop_after_batches`` stops early (used to test resuming). ``warn``
    receives one line per trial record that failed its check.

    In a ``jax.distributed`` job (``armimp_jax.study.distributed``) call it in every process with
    the same arguments: each process computes its shards of every batch, and only process
    0 writes the trial records.
    """
    with open_run(settings, out, warn=warn) as (_, todo):
        return _compute(settings, out, todo, batch_size, chunk_seconds, progress, stop_after_batches)


def _compute(settings, out, todo, batch_size, chunk_seconds, progress, stop_after_batches) -> list[str]:
    levels = sorted({c.perturbation for c in settings.conditions})  # IMBIC runs at level 1 whatever PD's
    mesh = make_mesh()
    per_trial = settings.n_samples * settings.substeps
    total, done_substeps, computed = len(todo) * per_trial, 0, []
    start = time.perf_counter()
    cache: dict[int, tuple] = {}
    write = distributed.is_writer()  # every process gets every result (to_host); one writes

    def signals(seed):
        if seed not in cache:
            cache[seed] = draw_perturbations(settings, seed, levels)
        return cache[seed]

    groups: dict[tuple, list] = {}
    for c, s in todo:
        groups.setdefault((c.controller, c.acquisition), []).append((c, s))
    batches = [g[i : i + batch_size] for g in groups.values() for i in range(0, len(g), batch_size)]
    for b_index, batch in enumerate(batches):
        if stop_after_batches is not None and b_index >= stop_after_batches:
            break
        t_batch = time.perf_counter()
        params = stack_trials(
            [
                trial(c.controller, c.friction, c.location, mhat=settings.mhat * np.eye(2), acquisition=c.acquisition)
                for c, _ in batch
            ]
        )
        f_delta = np.stack([signals(s)[0][c.perturbation] for c, s in batch])
        base_done = done_substeps

        def on_chunk(trial_samples, _total, _elapsed, base_done=base_done):
            now = base_done + trial_samples * settings.substeps
            elapsed = time.perf_counter() - start
            rate = now / elapsed if elapsed > 0 else 0.0
            if progress is not None:
                progress(
                    dict(
                        done=now,
                        total=total,
                        trials_done=len(computed),
                        trials_total=len(todo),
                        elapsed_s=elapsed,
                        eta_s=(total - now) / rate if rate > 0 else float("nan"),
                    )
                )

        sim = simulate_batch(
            params,
            f_delta,
            numerics=settings.numerics,
            mesh=mesh,
            chunk_samples=int(chunk_seconds * 1000),
            progress=on_chunk,
        )
        outcome = assess_batch(params, f_delta, sim, settings.welch, mesh=mesh)
        done_substeps += len(batch) * per_trial
        wall = time.perf_counter() - t_batch
        for i, (c, s) in enumerate(batch):
            est = {name: np.asarray(getattr(outcome.estimate, name)[i]) for name in ESTIMATE_FIELDS}
            _, coh, attempt = signals(s)
            tid = trial_id(c, s)
            meta = dict(
                id=tid,
                condition=dataclasses.asdict(c),
                seed=s,
                perturbation_attempt=attempt,
                input_coherence_max=coh,
                diverged=bool(sim.diverged[i]),
                diverged_at=int(sim.diverged_at[i]),
                batch_wall_s=wall,
                batch_size=len(batch),
                metrics=trial_metrics(est["f"], est["Z"], est, c.location),
            )
            if write:
                save_record(trial_path(out, c, s), settings=settings.trial_settings(c, s), arrays=est, meta=meta)
            computed.append(tid)
    return computed


def load_trials(
    out, settings: ReproSettings, *, warn: Callable[[str], None] = warn_stderr
) -> tuple[list[dict], dict, list[str]]:
    """The run's trials that pass their check: metadata list, ``{id: arrays}``, and the ids
    of the trials that are missing or failed (the latter named in a warning)."""
    records, missing = _record_status(_trials(settings, out), warn=warn, note="left out")
    metas = [rec.meta for rec in records.values()]
    arrays = {rec.meta["id"]: rec.arrays for rec in records.values()}
    return metas, arrays, [trial_id(c, s) for c, s in missing]


def add_fits(metas: list[dict], arrays: dict) -> None:
    """Add the fitted ``M, B, K`` of each trial (``claims.fit_metrics``, from its stored ``f``
    and ``Z``) to its ``metrics``, in place. Done when aggregating, so that every record,
    older ones included, gets the same fit, and the records stay as they were written."""
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
    with run_folder(out).lock():
        run = read_run(out)
        settings = ReproSettings.from_saved(run["settings"], where=str(out / "run.json"))
        metas, arrays, missing = load_trials(out, settings, warn=warn)
        add_fits(metas, arrays)
        summary = condition_summary(metas)
        claims = [dataclasses.asdict(c) for c in evaluate_claims(summary, seed_summaries(metas))]
        results = to_jsonable(  # as load_results reads it back: NaN -> None
            dict(
                format=RUN_FORMAT,
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
    if not isinstance(results, dict) or results.get("format") != RUN_FORMAT:
        raise ResultsError(f"{out / 'results.json'}: written by an older armimp_jax: rerun the reproduction")
    if settings_key(results["settings"]) != results["key"]:
        raise ResultsError(f"{out / 'results.json'}: its settings were edited (key mismatch)")
    rec = load_record(out / "results.npz", settings=results["settings"])
    ids = [str(i) for i in rec.arrays["trial_ids"]]
    if ids != [t["id"] for t in results["trials"]]:
        raise ResultsError(f"{out / 'results.npz'}: holds other trials than results.json")
    arrays = {tid: {k: rec.arrays[k][j] for k in ESTIMATE_FIELDS if k in rec.arrays} for j, tid in enumerate(ids)}
    return results, arrays


# --- tables -------------------------------------------------------------------------------

CONDITION_DTYPES = (
    dict(label=STRING, experiment=STRING, controller=STRING)
    | dict.fromkeys(("location", "friction", "perturbation", "n", "trials", "diverged"), INTEGER)
    | dict(acquisition=STRING)
)
FIT_DTYPES = CONDITION_DTYPES | dict(matrix=STRING, element=STRING, unit=STRING)
CLAIM_DTYPES = dict(key=STRING, verdict=STRING, robust="boolean", seeds=INTEGER)
CLAIM_DTYPES |= dict.fromkeys(("robustness", "ours", "claim", "rule", "left_out"), STRING)
_ELEMENTS = ("11", "12", "21", "22")  # (2, 2) matrices as rows or columns, [output, input], row-major
_FIT_UNITS = dict(M="kg", B="N s/m", K="N/m")


def _stats(prefix: str, mean, sd, half) -> dict:
    """``<prefix>_mean``, ``_sd``, ``_ci_lo``, ``_ci_hi`` of one number (``None``: undefined)."""
    nan = float("nan")
    mean, sd = (nan if v is None else v for v in (mean, sd))
    lo, hi = (nan, nan) if half is None else (mean - half, mean + half)
    return {f"{prefix}_mean": mean, f"{prefix}_sd": sd, f"{prefix}_ci_lo": lo, f"{prefix}_ci_hi": hi}


def _cells(value) -> list:
    """A (2, 2) list of a condition's means (``None`` where undefined) as four numbers."""
    return [None] * 4 if value is None else np.asarray(value, dtype=float).reshape(-1).tolist()


def _condition(entry: dict) -> dict:
    c = entry["condition"]
    return dict(label=Condition(**c).label, **c, n=entry["n"], trials=entry["trials"], diverged=entry["diverged"])


def conditions_frame(results: dict) -> pd.DataFrame:
    """One row per condition of ``results`` (``aggregate``'s): its fields and label, ``n``
    (trials that did not diverge), ``trials``, ``diverged``, and for every scalar metric
    (``phi_ij`` as ``phi_11`` .. ``phi_22``) ``<m>_mean``, ``<m>_sd`` and the 95% t-interval
    ``<m>_ci_lo``, ``<m>_ci_hi`` over the seeds (NaN where undefined). The fitted matrices
    are in ``fits_frame``."""
    rows = []
    for entry in results["conditions"]:
        row = _condition(entry)
        for m in (k for k in entry if k + "_sd" in entry and k + "_ci" in entry):
            if m == "phi_ij":
                cells = zip(_ELEMENTS, *(_cells(entry[m + s]) for s in ("", "_sd", "_ci")), strict=True)
                for e, mean, sd, half in cells:
                    row |= _stats(f"phi_{e}", mean, sd, half)
            elif not isinstance(entry[m], list):
                row |= _stats(m, entry[m], entry[m + "_sd"], entry[m + "_ci"])
        rows.append(row)
    return table(rows, CONDITION_DTYPES)


def fits_frame(results: dict) -> pd.DataFrame:
    """The fitted ``M``, ``B``, ``K`` of ``results`` (``aggregate``'s) in long form: one row
    per condition, matrix and element (``11``: [output x, input x]), with the arm's true
    value, the mean fit over the seeds with its standard deviation and 95% t-interval, the
    matrix's mean relative error ``||fit - true||_F / ||true||_F`` and the fit's mean overall
    VAF [%]. Results written before the fit existed give no rows."""
    rows = []
    for entry in results["conditions"]:
        if "truth" not in entry or "fit_M" not in entry:
            continue
        for sym, unit in _FIT_UNITS.items():
            key = f"fit_{sym}"
            cells = zip(_ELEMENTS, _cells(entry["truth"][sym]), *(_cells(entry[key + s]) for s in ("", "_sd", "_ci")))
            for e, true, mean, sd, half in cells:
                row = _condition(entry) | dict(matrix=sym, element=e, unit=unit, true=true)
                row |= {k.replace("fit_", "", 1): v for k, v in _stats("fit", mean, sd, half).items()}
                row |= dict(rel_error=entry[key + "_rel_error"], vaf=entry.get("fit_vaf"))
                rows.append(row)
    return table(rows, FIT_DTYPES, columns=None if rows else list(FIT_DTYPES))


def claims_frame(results: dict) -> pd.DataFrame:
    """The claims (a)-(f) of ``results`` (``aggregate``'s), one row each: ``verdict`` (from the
    condition means), ``robust`` (``<NA>`` under two seeds), ``seeds`` judged alone, the
    ``robustness`` and ``ours`` texts, the paper's ``claim``, the ``rule``, and the conditions
    ``left_out`` (every trial diverged; joined by "; "; ``<NA>``: none)."""
    rows = [
        {k: c[k] for k in ("key", "verdict", "robust", "seeds", "robustness", "ours", "claim", "rule")}
        | dict(left_out="; ".join(c["left_out"]) or None)
        for c in results["claims"]
    ]
    return table(rows, CLAIM_DTYPES, columns=list(CLAIM_DTYPES))


def result_tables(results: dict) -> dict[str, pd.DataFrame]:
    """``{"conditions": conditions_frame, "claims": claims_frame, "fits": fits_frame}`` of
    ``results``: the reproduction's tidy tables."""
    return dict(conditions=conditions_frame(results), claims=claims_frame(results), fits=fits_frame(results))


def load_tables(out) -> dict[str, pd.DataFrame]:
    """The tidy tables (``result_tables``) of the aggregated run in folder ``out``, from its
    checked ``results.json`` and ``results.npz`` (``load_results``)."""
    return result_tables(load_results(pathlib.Path(out))[0])
