"""The one engine of every study: ``run(spec, out)`` owns the run folder, the lock, resume,
the perturbation cache, the batch loop, progress and the records.

A study is a *specification* (``Spec``): a frozen settings object that names its run
folder's kind, lists its trials, says which of them may share a compiled batch, and how to
build and measure a batch (``runner``). The sweep (``study.sweep.sweep.SweepSettings``), the
friction threshold (``study.sweep.threshold``), the paper reproduction
(``paper.reproduce.ReproSettings``), the claim explanations (``paper.explain``), the tuner
(``paper.mhat_experiment``) and the benchmarks' resumable runs (``study.sweep.coverage``) are
specifications; none has a loop, a cache or a resume of its own.

- ``run``: open (or resume) the run in ``out`` (``StudyRun.open``: the lock, ``run.json``
  written or checked, the trials without a valid record), run those trials in ``batches``
  and save each as a checked record as soon as its batch finishes (an interrupted run keeps
  every finished batch), report progress after every chunk, then call ``finish`` with the
  ``StudyRun`` while the lock is still held.
- ``SimulationSpec``: the runner of a study whose batch is one ``simulate_batch`` (and
  ``assess_batch``): it supplies ``build`` (the stacked trials and their perturbations) and
  ``measure`` (the records).
- ``Perturbations``: the perturbation cache of a run (``study.runs.seeds``: common random numbers).
- ``records``: the checked records of a finished (or partial) run, for the collectors.
- ``batches``, ``map_batches``: the batch split, also for studies that keep no folder.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Hashable, Mapping, Sequence
from typing import Any, ClassVar, NamedTuple, Protocol

import numpy as np

from . import distributed
from .results import Record
from .runfolder import StudyRun, warn_stderr
from .seeds import seed_perturbation, sensor_noise_key

# What the engine adds to every record's meta (a spec may place the keys, e.g. as None,
# to fix their position in the record).
BATCH_FIELDS = ("batch_wall_s", "batch_size")


class Perturbations:
    """The perturbations of a run's seeds, each drawn once (``study.runs.seeds``): seed ``s`` from
    ``fold_in(PRNGKey(base_seed), s)`` (``redraw`` > 0 folds the attempt in once more), at
    ``n`` samples scaled to ``peak`` [N] per axis; ``noise_key`` is the seed's sensor-noise key."""

    def __init__(self, base_seed: int = 0):
        self.base_seed = base_seed
        self.cache: dict = {}
        self.derived: dict = {}

    def __call__(self, seed: int, n: int, peak, *, redraw: int = 0) -> np.ndarray:
        key = (seed, n, tuple(np.ravel(np.asarray(peak, dtype=float)).tolist()), redraw)
        if key not in self.cache:
            self.cache[key] = seed_perturbation(self.base_seed, seed, n, peak, redraw=redraw)
        return self.cache[key]

    def noise_key(self, seed: int) -> np.ndarray:
        return sensor_noise_key(self.base_seed, seed)

    def keep(self, key: Hashable, make: Callable[[], Any]) -> Any:
        """What ``make()`` derives from the run's signals (a seed's draws over levels, their
        coherence), made once per run under ``key``."""
        if key not in self.derived:
            self.derived[key] = make()
        return self.derived[key]


class Context(NamedTuple):
    """What a batch runner gets once per run: the ``StudyRun`` (its earlier records), the
    device ``mesh``, the ``chunk_samples`` of progress reports and the ``signals`` cache."""

    run: StudyRun
    mesh: Any
    chunk_samples: int
    signals: Perturbations


# runner(batch, progress) -> per trial (arrays, meta), in order; progress: simulate_batch's chunk callback
BatchRunner = Callable[[list, Callable], list[tuple[Mapping, Mapping]]]


class Spec(Protocol):
    """What the engine needs of a study's settings.

    ``KIND``, ``FORMAT`` and ``NOUN`` name its run folder (``StudyRun``). A *trial* is any
    hashable value (``(point index, seed)``, ``(Condition, seed)``) listed by ``trials()`` in
    run order; ``trial_record(trial)`` gives its record's file stem and the settings that
    fix its numbers; ``group(trial)`` what must agree within one compiled batch;
    ``samples(trial)`` its record length [samples] (the progress); ``runner(context)`` a
    function that runs one batch. ``base_seed`` (if any) seeds the run's ``Perturbations``.
    """

    KIND: ClassVar[str]
    FORMAT: ClassVar[int]
    NOUN: ClassVar[str]

    def validate(self) -> None: ...
    def run_settings(self) -> dict: ...
    def run_extra(self) -> dict: ...
    def describe(self, saved: Mapping, wanted: Mapping) -> str: ...
    def trials(self) -> list[Hashable]: ...
    def trial_record(self, trial: Hashable) -> tuple[str, dict]: ...
    def group(self, trial: Hashable) -> Hashable: ...
    def samples(self, trial: Hashable) -> int: ...
    def runner(self, context: Context) -> BatchRunner: ...


class Simulation(NamedTuple):
    """One batch as ``simulate_batch`` takes it: the stacked ``trials``, ``f_delta`` ``(B, N,
    2)`` [N], the ``numerics``, the sensor-noise ``keys`` (``None``: none drawn), the
    ``welch`` settings of ``assess_batch`` (``None``: the spec estimates for itself) and the
    run's ``signals`` (for ``measure``)."""

    trials: Any
    f_delta: np.ndarray
    numerics: Any
    keys: np.ndarray | None = None
    welch: Any = None
    signals: Perturbations | None = None


class SimulationSpec:
    """The runner of a study whose batch is one ``simulate_batch``: the spec supplies
    ``build(batch, signals) -> Simulation`` and ``measure(batch, simulation, sim, outcome)
    -> [(arrays, meta), ...]`` (``outcome``: ``assess_batch``'s, or ``None`` without ``welch``)."""

    def runner(self, context: Context) -> BatchRunner:
        from ..._batch import assess_batch, simulate_batch

        def run(batch, progress):
            built = self.build(batch, context.signals)._replace(signals=context.signals)
            sim = simulate_batch(
                built.trials,
                built.f_delta,
                keys=built.keys,
                numerics=built.numerics,
                mesh=context.mesh,
                chunk_samples=context.chunk_samples,
                progress=progress,
            )
            outcome = None
            if built.welch is not None:
                outcome = assess_batch(built.trials, built.f_delta, sim, built.welch, mesh=context.mesh)
            return self.measure(batch, built, sim, outcome)

        return run


# --- batches ----------------------------------------------------------------------------------


def batches(items: Sequence, group: Callable[[Any], Hashable], batch_size: int) -> list[list]:
    """``items`` split by ``group`` (first appearance order), each group into the fewest
    batches of at most ``batch_size``, of equal size (give or take one): one compiled
    shape per group."""
    groups: dict[Hashable, list] = {}
    for item in items:
        groups.setdefault(group(item), []).append(item)
    out = []
    for g in groups.values():
        per = math.ceil(len(g) / math.ceil(len(g) / batch_size))
        out += [g[j : j + per] for j in range(0, len(g), per)]
    return out


def map_batches(items: Sequence, group: Callable[[Any], Hashable], batch_size: int, run: Callable) -> list:
    """``run(batch)`` (a list of per-item results) over the ``batches`` of ``items``; the
    results in the order of ``items`` (for work that keeps no run folder)."""
    out: list = [None] * len(items)
    for batch in batches(range(len(items)), lambda i: group(items[i]), batch_size):
        for i, result in zip(batch, run([items[i] for i in batch]), strict=True):
            out[i] = result
    return out


# --- progress ---------------------------------------------------------------------------------


class Progress:
    """Counts a run's trial samples and reports after every chunk to ``report`` (a dict:
    ``done``/``total`` trial samples, ``trials_done``, ``trials_total``, ``elapsed_s``,
    ``eta_s``). The ETA's rate comes from the chunks that compiled nothing: the first
    chunk of a batch with a shape not seen before pays for compilation (NaN until a chunk
    has run without compiling). Estimating and saving a batch count towards the rate
    (they are part of every trial's cost). A batch that reports no chunk (a study that
    does not simulate in chunks) is reported once, when it ends."""

    def __init__(self, total: int, trials_total: int, report: Callable[[dict], None] | None):
        self.total, self.trials_total, self.report = total, trials_total, report
        self.start = self.last = time.perf_counter()
        self.done = self.trials = 0
        self.fresh_s = 0.0
        self.fresh_samples = 0
        self.shapes: set = set()
        self.reported = False

    def batch(self, shape: Hashable) -> Callable:
        """The chunk callback of the next batch (``simulate_batch(progress=...)``)."""
        base, compiling = self.done, [shape not in self.shapes]
        self.shapes.add(shape)
        self.reported = False

        def on_chunk(done, _total, _elapsed):
            now = time.perf_counter()
            if not compiling[0]:
                self.fresh_s += now - self.last
                self.fresh_samples += base + done - self.done
            compiling[0] = False
            self.last, self.done, self.reported = now, base + done, True
            if self.report is not None:
                self.report(self._state(now))

        return on_chunk

    def end_batch(self, samples: int, trials: int) -> None:
        """A batch of ``trials`` trials and ``samples`` trial samples is over."""
        self.trials += trials
        if not self.reported:
            now = time.perf_counter()
            self.done += samples
            self.last = now
            if self.report is not None:
                self.report(self._state(now))

    def _state(self, now: float) -> dict:
        rate = self.fresh_samples / self.fresh_s if self.fresh_s > 0 else math.nan
        return dict(
            done=self.done,
            total=self.total,
            trials_done=self.trials,
            trials_total=self.trials_total,
            elapsed_s=now - self.start,
            eta_s=(self.total - self.done) / rate if rate > 0 else math.nan,
        )


# --- running ----------------------------------------------------------------------------------


@dataclasses.dataclass
class Outcome:
    """What ``run`` did: the ``StudyRun``, the trials found ``done`` and those ``todo`` at the
    start, the record ids ``computed`` now (in order), whether it was ``interrupted``, and
    what ``finish`` returned (``None`` in the processes that do not write)."""

    run: StudyRun
    done: list
    todo: list
    computed: list[str]
    interrupted: bool = False
    finished: Any = None


def resumed(cls: type, out, change: Callable[[Any], Spec] | None = None):
    """The settings (a ``cls``, by its ``from_saved``) of the run in ``out``, to resume it;
    ``change(saved)`` gives the settings with the options given on the command line, which
    must not change the run (one line naming the difference otherwise)."""
    study = StudyRun.of(cls, out)
    saved = cls.from_saved(study.saved_settings(), where=str(study.run_file))
    if change is not None:
        study.check_resume(saved.run_settings(), change(saved).run_settings(), describe=saved.describe)
    return saved


def _trial_rows(spec: Spec) -> list[tuple[Hashable, str, dict]]:
    return [(t, *spec.trial_record(t)) for t in spec.trials()]


def records(
    spec: Spec, out: StudyRun | Any, *, warn: Callable[[str], None] = warn_stderr, note: str = "left out"
) -> tuple[dict[Hashable, Record], list]:
    """``(records, missing)``: ``{trial: Record}`` of ``spec``'s trials whose record in ``out``
    (a ``StudyRun`` or a folder) passes its check, and the trials without one, in order;
    every other existing record is named in a warning (``"<why>; <note>"``)."""
    study = out if isinstance(out, StudyRun) else StudyRun.of(spec, out)
    return study.status(_trial_rows(spec), warn=warn, note=note)


def run(
    spec: Spec,
    out,
    *,
    resume: bool = False,
    batch_size: int = 64,
    chunk_seconds: float = 5.0,
    progress: Callable[[dict], None] | None = None,
    on_start: Callable[[int, list[tuple[int, int]]], None] | None = None,
    finish: Callable[[StudyRun, Outcome], Any] | None = None,
    interruptible: bool = False,
    warn: Callable[[str], None] = warn_stderr,
    stop_after_batches: int | None = None,
) -> Outcome:
    """Run (or resume) the study ``spec`` in folder ``out``; returns its ``Outcome``.

    Validates ``spec``, then opens the run (``StudyRun.open``: the writing process holds the
    folder's lock until the end, a folder holding another run is refused in one line, and so
    is ``resume`` on a folder with no run; a damaged or foreign record is named through
    ``warn`` and run again). The trials without a valid record run in ``batches`` of at most
    ``batch_size`` per ``spec.group``; each trial is saved as a checked record as soon as
    its batch finishes (only the writing process writes; the engine adds ``batch_wall_s``
    [s] and ``batch_size`` to every record's meta).

    ``on_start(trials on disk, batches)`` is called once the folder is checked, before any
    computation (``batches``: ``(trials, trial samples)`` of each batch to run, in order);
    ``progress`` receives ``Progress``'s dict after every chunk of ``chunk_seconds`` of
    record; ``finish(run, outcome)``, called by the writing process
    with the lock still held, writes what the study makes of its records (its return is
    ``Outcome.finished``). With ``interruptible``, Ctrl-C stops the batches and ``finish``
    still runs (``Outcome.interrupted``). ``stop_after_batches`` stops early (to test
    resuming). In a ``jax.distributed`` job call it in every process with the same arguments.
    """
    spec.validate()
    study = StudyRun.of(spec, out)
    writer = distributed.is_writer()
    settings, rows = spec.run_settings(), _trial_rows(spec)
    opened = study.open(settings, rows, resume=resume, describe=spec.describe, extra=spec.run_extra(), warn=warn)
    with opened as (done, todo):
        plan = batches(todo, spec.group, batch_size)
        if on_start is not None and writer:
            on_start(len(done), [(len(b), sum(spec.samples(t) for t in b)) for b in plan])
        outcome = Outcome(study, done, todo, [])
        try:
            _run_batches(spec, study, plan, outcome, chunk_seconds, progress, stop_after_batches)
        except KeyboardInterrupt:
            if not (interruptible and writer):
                raise
            outcome.interrupted = True
        if finish is not None and writer:
            outcome.finished = finish(study, outcome)
    return outcome


def _run_batches(spec, study, plan, outcome, chunk_seconds, progress, stop_after_batches) -> None:
    from ..._batch import make_mesh

    signals = Perturbations(getattr(spec, "base_seed", 0))
    context = Context(study, make_mesh(), max(1, int(chunk_seconds * 1000)), signals)
    runner = spec.runner(context)
    tracker = Progress(sum(spec.samples(t) for b in plan for t in b), sum(len(b) for b in plan), progress)
    writer = distributed.is_writer()
    for index, batch in enumerate(plan):
        if stop_after_batches is not None and index >= stop_after_batches:
            break
        shape = getattr(spec, "compile_key", lambda b: (spec.group(b[0]), len(b)))(batch)
        t0 = time.perf_counter()
        results = runner(batch, tracker.batch(shape))
        batch_info = dict(batch_wall_s=time.perf_counter() - t0, batch_size=len(batch))
        for trial, (arrays, meta) in zip(batch, results, strict=True):
            record_id, settings = spec.trial_record(trial)
            if writer:  # every process holds every result (gathered); one writes
                study.save(record_id, settings=settings, arrays=arrays, meta=dict(meta) | batch_info)
            outcome.computed.append(record_id)
        tracker.end_batch(sum(spec.samples(t) for t in batch), len(batch))
