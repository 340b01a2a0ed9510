"""A study's run folder as a handle (``StudyRun``): ``run.json``, its lock, its trial records.

Every study that writes a folder (the sweep, the reproduction, the claim explanations, the
friction threshold, the tuner, the benchmarks' resumable runs) keeps one run in it, and
the engine (``study.runs.engine``), the collectors and the writers take the folder as a
``StudyRun``:

- ``read`` / ``saved_settings``: ``run.json`` checked (kind, format, and the key of its
  settings, so that an edited file is refused);
- ``prepare``: create the folder and write ``run.json``, or check that the run there has
  the settings asked for; another run is refused in one line naming the difference
  (``describe_difference``); ``resume`` needs a run to be there;
- ``check_resume``: options given with ``--resume`` must agree with the run's;
- ``lock``: the folder's ``RunLock`` (one process at a time);
- ``record_path``, ``status``, ``save``: where a trial's record lives, which records pass
  their check (the rest are to run, the damaged ones named in a warning), and writing one;
- ``open``: all of it at the start of a run, in every process of a ``jax.distributed``
  job (process 0 holds the lock and reads the folder; the others get its list).

Every refusal is a ``ResultsError`` with a one-line message. ``docs/results.md`` has the rules.
"""

from __future__ import annotations

import contextlib
import datetime
import json
import os
import pathlib
import secrets
import socket
import sys
import time
from collections.abc import Callable, Hashable, Iterable, Iterator, Mapping
from typing import Any

from . import distributed
from .results import (
    Record,
    ResultsError,
    _one_line,
    atomic_write_json,
    describe_difference,
    load_record,
    read_json,
    save_record,
    settings_key,
    stamped,
)

RUN_FILE = "run.json"
RECORDS = "trials"  # the subfolder of trial records

Describe = Callable[[Mapping, Mapping], str]  # (saved settings, wanted settings) -> one line
Trials = Iterable[tuple[Hashable, str, Mapping]]  # (trial, record id, trial settings)


def warn_stderr(message: str) -> None:
    """The default ``warn``: one line ``warning: MESSAGE`` on stderr."""
    sys.stderr.write(f"warning: {message}\n")


class StudyRun:
    """The run folder ``path`` of a study of ``kind`` whose ``run.json`` layout is ``format``.

    Args:
        path: the folder.
        kind: the study (``"sweep"``, ``"reproduction"``, ``"tuning"``, ...), written into
            ``run.json`` and checked when it is read.
        format: the layout version of this kind's ``run.json``; another is refused.
        noun: what the messages call the run (``"sweep"``, ``"run"``).
        records: the subfolder of the trial records, which ``prepare`` creates (``None``: none).
    """

    def __init__(
        self,
        path: pathlib.Path | str,
        *,
        kind: str,
        format: int,
        noun: str = "run",
        records: str | None = RECORDS,
    ):
        self.path = pathlib.Path(path)
        self.kind, self.format, self.noun, self.records = kind, format, noun, records

    @classmethod
    def of(cls, spec, path) -> StudyRun:
        """The run folder ``path`` of a study of ``spec``'s kind (its ``KIND``, ``FORMAT``, ``NOUN``)."""
        return cls(path, kind=spec.KIND, format=spec.FORMAT, noun=spec.NOUN)

    def __repr__(self) -> str:
        return f"StudyRun({str(self.path)!r}, kind={self.kind!r})"

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

    def add_wall_time(self, seconds: float) -> float:
        """Add ``seconds`` to the run's ``wall_s`` in ``run.json``; returns the new total [s]."""
        total = (self.read().get("wall_s") or 0.0) + seconds
        self.update(wall_s=total)
        return total

    def check_resume(self, saved: Mapping, wanted: Mapping, *, describe: Describe = describe_difference) -> None:
        """Refuse (one line) options given with ``--resume`` that change the run's ``saved``
        settings: ``wanted`` is the saved run with those options applied."""
        if settings_key(saved) != settings_key(wanted):
            raise ResultsError(
                f"--resume {self.path}: that run has {describe(saved, wanted)}; drop those options to "
                f"finish it, or start a new {self.noun} with --out"
            )

    # --- trial records ---

    def record_path(self, record_id: str) -> pathlib.Path:
        """Where the record of trial ``record_id`` lives."""
        return self.path / (self.records or "") / f"{record_id}.npz"

    def save(self, record_id: str, *, settings: Mapping, arrays: Mapping | None = None, meta: Mapping | None = None):
        """Write the checked record of trial ``record_id`` (``results.save_record``)."""
        return save_record(self.record_path(record_id), settings=settings, arrays=arrays, meta=meta)

    def status(
        self, trials: Trials, *, warn: Callable[[str], None] = warn_stderr, note: str = "recomputing it"
    ) -> tuple[dict[Hashable, Record], list]:
        """``(records, todo)``: ``{trial: Record}`` of the ``(trial, record id, settings)`` whose
        record passes its check under the trial's settings, and the trials without one, in
        order; every other existing record is named in a warning (``"<why>; <note>"``)."""
        records, todo = {}, []
        for trial, record_id, settings in trials:
            path = self.record_path(record_id)
            if path.exists():
                try:
                    records[trial] = load_record(path, settings=settings)
                    continue
                except ResultsError as err:
                    warn(f"{err}; {note}")
            todo.append(trial)
        return records, todo

    @contextlib.contextmanager
    def open(
        self,
        settings: Mapping,
        trials: Trials,
        *,
        resume: bool = False,
        describe: Describe = describe_difference,
        extra: Mapping | None = None,
        warn: Callable[[str], None] = warn_stderr,
    ) -> Iterator[tuple[list, list]]:
        """Context manager that starts (or resumes) a run with ``settings`` and yields ``(done,
        todo)``: the ``trials`` (``(trial, record id, settings)``) with a valid record, and the
        rest, in order.

        The writing process (``distributed.is_writer()``: process 0, or the only one) holds the
        folder's lock until the block ends and calls ``prepare`` (a folder holding another run
        is refused; so is ``resume`` on a folder with no run) and ``status``. In a
        ``jax.distributed`` job every process gets process 0's lists, so all run the same
        batches in the same order, and a refusal is raised in every process.
        """
        trials = list(trials)
        with contextlib.ExitStack() as stack:
            todo = error = None
            if distributed.is_writer():
                try:
                    stack.enter_context(self.lock())
                    self.prepare(settings, resume=resume, describe=describe, extra=extra)
                    _, todo = self.status(trials, warn=warn)
                except Exception as err:  # shared with the other processes, then raised
                    error = err
            order = [trial for trial, _, _ in trials]
            todo = distributed.share_start(settings_key(settings), order, todo, error)
            wanted = set(todo)
            yield [trial for trial in order if trial not in wanted], todo


# --- the lock -----------------------------------------------------------------------------

LOCK_NAME = ".lock"
_HELD: dict[pathlib.Path, list] = {}  # lock path -> [token, depth] for locks this process holds


def _process_start(pid: int) -> str | None:
    """The kernel's start time of ``pid`` (Linux: field 22 of /proc/<pid>/stat), to tell a
    reused pid from the original holder; ``None`` where unknown."""
    try:
        stat = pathlib.Path(f"/proc/{pid}/stat").read_text()
        return stat.rsplit(")", 1)[1].split()[19]
    except (OSError, IndexError):
        return None


def _alive(pid: int, started: str | None) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass  # exists, owned by someone else
    except OverflowError:
        return False
    now = _process_start(pid)
    return started is None or now is None or now == started


class RunLock:
    """Exclusive use of an output folder by one process (a context manager, re-entrant in
    the process that holds it).

    Entering creates ``folder/.lock`` with ``O_CREAT | O_EXCL`` holding the pid, host, start
    time and a random token; leaving removes it. If the file exists, its holder is named in
    a ``ResultsError``, unless the holder is a process on this host that is gone (a crash or
    ``kill -9``), in which case the lock is taken over. A lock held from another host is
    never taken over: remove the file by hand once that run is known to be dead.
    """

    def __init__(self, folder: pathlib.Path | str):
        self.folder = pathlib.Path(folder)
        self.path = self.folder / LOCK_NAME

    def _info(self, token: str) -> dict:
        return dict(
            pid=os.getpid(),
            host=socket.gethostname(),
            started=datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
            process_start=_process_start(os.getpid()),
            token=token,
        )

    def _read(self) -> dict | None:
        try:
            info = json.loads(self.path.read_text())
            return info if isinstance(info, dict) and "pid" in info else None
        except (OSError, ValueError):
            return None

    def holder(self) -> dict | None:
        """The lock file's contents (pid, host, started), or ``None`` if the folder is free."""
        return self._read()

    def __enter__(self) -> RunLock:
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise ResultsError(f"output folder {self.folder} cannot be created: {_one_line(err)}") from None
        self.path = (self.folder / LOCK_NAME).resolve()
        if self.path in _HELD:
            _HELD[self.path][1] += 1
            return self
        token = secrets.token_hex(8)
        for _ in range(5):
            try:
                fd = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
            except FileExistsError:
                self._check_holder()
                continue
            except OSError as err:
                raise ResultsError(f"output folder {self.folder} is not writable: {_one_line(err)}") from None
            with os.fdopen(fd, "w") as fh:
                fh.write(json.dumps(self._info(token)))
                fh.flush()
                os.fsync(fh.fileno())
            _HELD[self.path] = [token, 1]
            return self
        raise ResultsError(f"{self.folder}: could not take the lock file {self.path} (another run keeps taking it)")

    def _check_holder(self) -> None:
        info = self._read()
        if info is None:
            # being written this instant, or damaged: a damaged one older than a minute is stale
            try:
                age = datetime.datetime.now().timestamp() - self.path.stat().st_mtime
            except FileNotFoundError:
                return
            if age < 60:
                raise ResultsError(f"{self.folder} is in use by another run (lock file {self.path} being written)")
            self._break(None)
            return
        here = info.get("host") == socket.gethostname()
        if here and not _alive(int(info["pid"]), info.get("process_start")):
            self._break(info)
            return
        raise ResultsError(
            f"{self.folder} is in use by another run: pid {info['pid']} on {info.get('host', '?')} since "
            f"{info.get('started', '?')} (lock file {self.path}); wait for it to finish"
            + ("" if here else ", or delete the lock file if that run is dead")
        )

    def _break(self, stale: dict | None) -> None:
        # Move the stale file aside atomically, then check it was the one we judged stale:
        # if another process took the lock over in between, put its file back.
        aside = self.path.with_name(f"{LOCK_NAME}.stale.{os.getpid()}.{secrets.token_hex(4)}")
        try:
            os.rename(self.path, aside)
        except FileNotFoundError:
            return
        try:
            moved = json.loads(aside.read_text())
        except (OSError, ValueError):
            moved = None
        if stale is not None and moved != stale:
            with contextlib.suppress(OSError):
                os.link(aside, self.path)
        with contextlib.suppress(OSError):
            aside.unlink()

    def __exit__(self, *exc) -> None:
        held = _HELD.get(self.path)
        if held is None:
            return
        held[1] -= 1
        if held[1] > 0:
            return
        del _HELD[self.path]
        info = self._read()
        if info is not None and info.get("token") == held[0]:
            with contextlib.suppress(FileNotFoundError):
                self.path.unlink()
