"""The run-trials engine of every study: run folder, batches, progress and resume, written once.

A study is a *specification* (``Spec``): a frozen settings object that names its run
folder's kind, lists its trials, says which of them may share a compiled batch and runs
one batch. The sweep (``study.sweep.SweepSettings``) and the paper reproduction
(``paper.reproduce.ReproSettings``) are specifications; the claim explanations
(``sweeps/explain_claims.py``), which keep no folder, use ``batches`` and ``map_batches``.

- ``run_folder``, ``saved_settings``, ``check_resume``, ``add_wall_time``: the study's run
  folder (``study.runfolder``: ``run.json`` checked, refused in one line when it holds
  another run).
- ``trial_status``: which trial records pass their check under their trial's settings.
- ``open_study``: the start of a run (lock, ``run.json``, the trials still to run), in
  every process of a ``jax.distributed`` job.
- ``run_trials``: the trials to run, in equal batches per group, each saved as a checked
  record as soon as its batch finishes (so an interrupted run keeps every finished
  batch), with a progress report after every chunk.
"""

from __future__ import annotations

import math
import pathlib
import time
from collections.abc import Callable, Hashable, Mapping, Sequence
from typing import Any, ClassVar, Protocol

from .._batch import make_mesh
from . import distributed
from .results import Record, save_record
from .runfolder import Describe, RunFolder, open_run, warn_stderr
from .runfolder import trial_status as _record_status

RECORDS = "trials"  # the run folder's subfolder of trial records
# What the engine adds to every record's meta (a spec may place the keys, e.g. as None,
# to fix their position in the record).
BATCH_FIELDS = ("batch_wall_s", "batch_size")

# run(batch, mesh=..., chunk_samples=..., progress=...) -> per trial (arrays, meta), in order
BatchRunner = Callable[..., list[tuple[Mapping, Mapping]]]


class Spec(Protocol):
    """What the engine needs of a study's settings.

    ``KIND``, ``FORMAT`` and ``NOUN`` name its run folder (``RunFolder``). A *trial* is any
    hashable value (``(point index, seed)``, ``(Condition, seed)``) listed by ``trials()`` in
    run order; ``trial_record(trial)`` gives its record's file stem and the settings that
    fix its numbers; ``group(trial)`` what must agree within one compiled batch;
    ``samples(trial)`` its record length [samples]; ``batch_runner()`` a fresh function
    that runs one batch (caches such as drawn perturbations live for one run).
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
    def batch_runner(self) -> BatchRunner: ...


# --- the run folder ---------------------------------------------------------------------------


def run_folder(spec: Spec | type, out) -> RunFolder:
    """The run folder ``out`` of a study of ``spec``'s kind (``study.runfolder``)."""
    return RunFolder(out, kind=spec.KIND, format=spec.FORMAT, noun=spec.NOUN)


def saved_settings(cls: type, out):
    """The settings (a ``cls``) of the run in ``out``, checked, to resume it."""
    folder = run_folder(cls, out)
    return cls.from_saved(folder.saved_settings(), where=str(folder.run_file))


def check_resume(out, saved: Spec, wanted: Spec) -> None:
    """Refuse (one line) options given with ``--resume out`` that change the run there:
    ``wanted`` is the ``saved`` run with those options applied."""
    run_folder(saved, out).check_resume(saved.run_settings(), wanted.run_settings(), describe=saved.describe)


def prepare(spec: Spec, out, *, resume: bool = False) -> dict:
    """Create ``out`` and write ``run.json`` for ``spec``, or check that the run there has its
    settings (another run is refused in one line naming the differences; so is ``resume``
    on a folder with no run); returns ``run.json``. ``open_study`` does this under the lock."""
    return run_folder(spec, out).prepare(
        spec.run_settings(), resume=resume, describe=spec.describe, extra=spec.run_extra()
    )


def add_wall_time(spec: Spec | type, out, seconds: float) -> float:
    """Add ``seconds`` to the run's ``wall_s`` in ``run.json``; returns the new total [s]."""
    folder = run_folder(spec, out)
    total = (folder.read().get("wall_s") or 0.0) + seconds
    folder.update(wall_s=total)
    return total


def record_path(out, record_id: str) -> pathlib.Path:
    """Where the record of trial ``record_id`` lives in run folder ``out``."""
    return pathlib.Path(out) / RECORDS / f"{record_id}.npz"


def trial_list(spec: Spec, out) -> list[tuple[Hashable, pathlib.Path, dict]]:
    """``(trial, record path, trial settings)`` of every trial of ``spec``, in run order."""
    rows = []
    for trial in spec.trials():
        record_id, settings = spec.trial_record(trial)
        rows.append((trial, record_path(out, record_id), settings))
    return rows


def trial_status(
    spec: Spec, out, *, warn: Callable[[str], None] = warn_stderr, note: str = "recomputing it"
) -> tuple[dict[Hashable, Record], list]:
    """``(records, todo)``: ``{trial: Record}`` of the trials whose record passes its check,
    and the trials still to run, in order; every other existing record is named in a
    warning (``"<why>; <note>"``)."""
    return _record_status(trial_list(spec, out), warn=warn, note=note)


def open_study(spec: Spec, out, *, resume: bool = False, warn: Callable[[str], None] = warn_stderr):
    """Context manager that starts (or resumes) the run of ``spec`` in ``out`` and yields
    ``(done, todo)`` lists of trials (``study.runfolder.open_run``).

    Validates ``spec`` first. The writing process (``distributed.is_writer()``) holds
    ``out``'s ``RunLock`` until the block ends and writes or checks ``run.json`` (a folder
    holding another run is refused in one line; so is ``resume`` on a folder with no run).
    In a ``jax.distributed`` job every process gets process 0's lists, so all run the same
    batches in the same order, and a refusal is raised in every process."""
    spec.validate()
    describe: Describe = spec.describe
    return open_run(
        run_folder(spec, out),
        spec.run_settings(),
        trial_list(spec, out),
        resume=resume,
        describe=describe,
        extra=spec.run_extra(),
        warn=warn,
    )


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
    results in the order of ``items``."""
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
    (they are part of every trial's cost)."""

    def __init__(self, total: int, trials_total: int, report: Callable[[dict], None] | None):
        self.total, self.trials_total, self.report = total, trials_total, report
        self.start = self.last = time.perf_counter()
        self.done = self.trials = 0
        self.fresh_s = 0.0
        self.fresh_samples = 0
        self.shapes: set = set()

    def batch(self, shape: Hashable) -> Callable:
        """The chunk callback of the next batch (``simulate_batch(progress=...)``)."""
        base, compiling = self.done, [shape not in self.shapes]
        self.shapes.add(shape)

        def on_chunk(done, _total, _elapsed):
            now = time.perf_counter()
            if not compiling[0]:
                self.fresh_s += now - self.last
                self.fresh_samples += base + done - self.done
            compiling[0] = False
            self.last, self.done = now, base + done
            if self.report is not None:
                self.report(self._state(now))

        return on_chunk

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


def run_trials(
    spec: Spec,
    out,
    todo: Sequence,
    *,
    batch_size: int = 64,
    chunk_seconds: float = 5.0,
    progress: Callable[[dict], None] | None = None,
    stop_after_batches: int | None = None,
) -> list[str]:
    """Run the ``todo`` trials of ``spec`` in ``batches`` and save each as a checked record
    in ``out`` as soon as its batch finishes (only the writing process writes); returns
    the record ids computed, in order.

    ``progress`` receives ``Progress``'s dict after every chunk of ``chunk_seconds`` of
    record. ``stop_after_batches`` stops early (to test resuming). The engine sets
    ``batch_wall_s`` [s] and ``batch_size`` in every record's meta."""
    mesh = make_mesh()
    run = spec.batch_runner()
    tracker = Progress(sum(spec.samples(t) for t in todo), len(todo), progress)
    computed = []
    for b_index, batch in enumerate(batches(todo, spec.group, batch_size)):
        if stop_after_batches is not None and b_index >= stop_after_batches:
            break
        shape = getattr(spec, "compile_key", lambda b: (spec.group(b[0]), len(b)))(batch)
        t0 = time.perf_counter()
        results = run(batch, mesh=mesh, chunk_samples=max(1, int(chunk_seconds * 1000)), progress=tracker.batch(shape))
        batch_info = dict(batch_wall_s=time.perf_counter() - t0, batch_size=len(batch))
        for trial, (arrays, meta) in zip(batch, results, strict=True):
            record_id, settings = spec.trial_record(trial)
            if distributed.is_writer():  # every process holds every result (gathered); one writes
                save_record(record_path(out, record_id), settings=settings, arrays=arrays, meta=dict(meta) | batch_info)
            computed.append(record_id)
        tracker.trials += len(batch)
    return computed
