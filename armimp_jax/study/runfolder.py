"""One run per folder: the protocol of every study that writes one (sweeps, the reproduction, the tuner).

A run folder holds ``run.json``: the study's ``kind``, the ``format`` of its layout, the
run's *settings* (every value that changes a number, stamped with the package version)
and their ``key``, plus what the study adds (library versions, wall time, options). The
pieces, used the same way by ``study.sweep``, ``paper.reproduce`` and
``sweeps/tune_mhat.py``:

- ``RunFolder.read`` / ``saved_settings``: ``run.json`` checked (kind, format, and the key
  of its settings, so that an edited file is refused);
- ``RunFolder.prepare``: create the folder and write ``run.json``, or check that the run
  there has the settings asked for; another run is refused in one line naming the
  difference (``describe_difference``); ``resume`` needs a run to be there;
- ``RunFolder.check_resume``: options given with ``--resume`` must agree with the run's;
- ``RunFolder.lock``: the folder's ``RunLock`` (one process at a time);
- ``trial_status``: which trial records pass their check (the rest are to run, the
  damaged ones named in a warning);
- ``open_run``: all of it at the start of a run, in every process of a ``jax.distributed``
  job (process 0 holds the lock and reads the folder; the others get its list).

Every refusal is a ``ResultsError`` with a one-line message. ``docs/results.md`` has the rules.
"""

from __future__ import annotations

import contextlib
import pathlib
import sys
import time
from collections.abc import Callable, Hashable, Iterable, Iterator, Mapping
from typing import Any

from . import distributed
from .results import (
    Record,
    ResultsError,
    RunLock,
    atomic_write_json,
    describe_difference,
    load_record,
    read_json,
    settings_key,
    stamped,
)

RUN_FILE = "run.json"

Describe = Callable[[Mapping, Mapping], str]  # (saved settings, wanted settings) -> one line


def warn_stderr(message: str) -> None:
    """The default ``warn``: one line ``warning: MESSAGE`` on stderr."""
    sys.stderr.write(f"warning: {message}\n")


class RunFolder:
    """The run folder ``path`` of a study of ``kind`` whose ``run.json`` layout is ``format``.

    Args:
        path: the folder.
        kind: the study (``"sweep"``, ``"reproduction"``, ``"tuning"``), written into
            ``run.json`` and checked when it is read.
        format: the layout version of this kind's ``run.json``; another is refused.
        noun: what the messages call the run (``"sweep"``, ``"run"``).
        records: the subfolder that ``prepare`` creates for the trial records (``None``: none).
    """

    def __init__(
        self, path: pathlib.Path | str, *, kind: str, format: int, noun: str = "run", records: str | None = "trials"
    ):
        self.path = pathlib.Path(path)
        self.kind, self.format, self.noun, self.records = kind, format, noun, records

    @property
    def run_file(self) -> pathlib.Path:
        return self.path / RUN_FILE

    def lock(self) -> RunLock:
        """The folder's ``RunLock`` (re-entrant in the process that holds it)."""
        return RunLock(self.path)

    def has_run(self) -> bool:
        return self.run_file.exists()

    def read(self) -> dict:
        """``run.json``, checked: a ``ResultsError`` names a missing folder or file, another
        kind or format, and settings edited after the run (their key does not match)."""
        if not self.path.is_dir():
            raise ResultsError(f"{self.path}: no such folder")
        if not self.has_run():
            raise ResultsError(f"{self.path} holds no {self.noun} (no {RUN_FILE})")
        run = read_json(self.run_file)
        if not isinstance(run, dict):
            run = {}
        kind = run.get("kind", self.kind)  # reproductions wrote no "kind" before this protocol
        if kind != self.kind or run.get("format") != self.format or not {"settings", "key"} <= run.keys():
            raise ResultsError(
                f"{self.run_file}: not the {RUN_FILE} of a {self.noun} of this armimp_jax (kind {kind!r}, format "
                f"{run.get('format')!r}; expected {self.kind!r}, format {self.format}): use another output folder"
            )
        if settings_key(run["settings"]) != run["key"]:
            raise ResultsError(f"{self.run_file}: its settings were edited after the run (key mismatch)")
        return run

    def saved_settings(self) -> dict:
        """The settings of the run in the folder (to resume it)."""
        return self.read()["settings"]

    def prepare(
        self,
        settings: Mapping,
        *,
        resume: bool = False,
        describe: Describe = describe_difference,
        extra: Mapping | None = None,
    ) -> dict:
        """Make the folder ready for a run with ``settings``; returns its ``run.json``.

        Creates the folder (and its ``records`` subfolder), checks it is writable, and writes ``run.json``
        (``kind``, ``format``, the stamped settings, their key, then ``extra``) unless one is
        there. A folder holding a run with other settings is refused in one line naming
        the differences (``describe(saved, wanted)``); so is ``resume`` on a folder with no
        run."""
        if resume and not self.has_run():
            raise ResultsError(f"{self.path} holds no {self.noun} to resume (no {RUN_FILE})")
        try:
            (self.path if self.records is None else self.path / self.records).mkdir(parents=True, exist_ok=True)
            probe = self.path / f".write-test-{time.time_ns()}"
            probe.write_text("ok")
            probe.unlink()
        except OSError as err:
            raise ResultsError(f"output folder {self.path} is not writable: {err}") from None
        wanted = stamped(settings)
        if self.has_run():
            run = self.read()
            made_by, this = run["settings"].get("armimp_jax"), wanted.get("armimp_jax")
            if made_by != this:  # the same settings under another version may give other numbers
                raise ResultsError(
                    f"{self.path} holds a {self.noun} made by armimp_jax {made_by}, and this is {this}: results of "
                    "two versions are never mixed; start it again in another folder (--out), or finish it with "
                    f"armimp_jax {made_by} (reading it, e.g. --replot, works)"
                )
            if run["key"] != settings_key(wanted):
                raise ResultsError(
                    f"{self.path} holds a {self.noun} with {describe(run['settings'], wanted)}: use another output "
                    f"folder (--out), or resume it with its own settings (--resume {self.path})"
                )
            return run
        run = dict(kind=self.kind, format=self.format, settings=wanted, key=settings_key(wanted)) | dict(extra or {})
        atomic_write_json(self.run_file, run)
        return run

    def update(self, **fields: Any) -> dict:
        """Rewrite ``run.json`` with ``fields`` changed (not its settings or key); returns it."""
        if {"kind", "format", "settings", "key"} & fields.keys():
            raise ValueError(f"update changes what a run adds to {RUN_FILE}, not {sorted(fields)}")
        run = self.read() | fields
        atomic_write_json(self.run_file, run)
        return run

    def check_resume(self, saved: Mapping, wanted: Mapping, *, describe: Describe = describe_difference) -> None:
        """Refuse (one line) options given with ``--resume`` that change the run's ``saved``
        settings: ``wanted`` is the saved run with those options applied."""
        if settings_key(saved) != settings_key(wanted):
            raise ResultsError(
                f"--resume {self.path}: that run has {describe(saved, wanted)}; drop those options to "
                f"finish it, or start a new {self.noun} with --out"
            )


Trials = Iterable[tuple[Hashable, pathlib.Path, Mapping]]  # (trial, record path, trial settings)


def trial_status(
    trials: Trials, *, warn: Callable[[str], None] = warn_stderr, note: str = "recomputing it"
) -> tuple[dict[Hashable, Record], list]:
    """``(records, todo)``: ``{trial: Record}`` of the trials whose record passes its check
    under the trial's settings, and the trials without one, in order; every other existing
    record is named in a warning (``"<why>; <note>"``)."""
    records, todo = {}, []
    for trial, path, settings in trials:
        if path.exists():
            try:
                records[trial] = load_record(path, settings=settings)
                continue
            except ResultsError as err:
                warn(f"{err}; {note}")
        todo.append(trial)
    return records, todo


@contextlib.contextmanager
def open_run(
    folder: RunFolder,
    settings: Mapping,
    trials: Trials,
    *,
    resume: bool = False,
    describe: Describe = describe_difference,
    extra: Mapping | None = None,
    warn: Callable[[str], None] = warn_stderr,
) -> Iterator[tuple[list, list]]:
    """Context manager that starts (or resumes) a run with ``settings`` in ``folder`` and
    yields ``(done, todo)``: the ``trials`` with a valid record, and the rest, in order.

    The writing process (``distributed.is_writer()``: process 0, or the only one) holds the
    folder's lock until the block ends and calls ``prepare`` (a folder holding another run
    is refused; so is ``resume`` on a folder with no run) and ``trial_status``. In a
    ``jax.distributed`` job every process gets process 0's lists, so all run the same
    batches in the same order, and a refusal is raised in every process.
    """
    trials = list(trials)
    with contextlib.ExitStack() as stack:
        todo = error = None
        if distributed.is_writer():
            try:
                stack.enter_context(folder.lock())
                folder.prepare(settings, resume=resume, describe=describe, extra=extra)
                _, todo = trial_status(trials, warn=warn)
            except Exception as err:  # shared with the other processes, then raised
                error = err
        order = [trial for trial, _, _ in trials]
        todo = distributed.share_start(settings_key(settings), order, todo, error)
        wanted = set(todo)
        yield [trial for trial in order if trial not in wanted], todo
