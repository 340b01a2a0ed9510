"""Saved results that always match their settings: keys, checked records, atomic writes, locks.

The study layer (the paper's reproduction, the tuner, sweeps) saves every result together
with the *settings* that made it: a JSON-able dict holding every value that changes a
number, and the package version. ``settings_key`` hashes them; a result is reused only when
its key equals the key of the settings asked for now. The pieces:

- ``strict_json_dumps``: JSON that other tools can read (``NaN`` and infinities become
  ``null``, NumPy scalars and arrays become numbers and lists).
- ``settings_key`` / ``describe_difference``: the key of a settings dict, and a one-line
  account of how two settings dicts differ (for refusals).
- ``atomic_write_bytes`` / ``atomic_write_text`` / ``atomic_write_json`` /
  ``atomic_write_npz``: a reader sees the old file or the new one, never a torn one (a
  uniquely named temporary file in the same folder, fsync, ``os.replace``).
- ``save_record`` / ``load_record``: one ``.npz`` file holding named arrays, the settings,
  their key, free metadata, and a SHA-256 digest of all of it; ``load_record`` names the
  file and says what is wrong when it is truncated, altered, or made with other settings.
Every refusal is a ``ResultsError`` (a ``ValueError``) with a one-line message.
The run folder that holds them, with its lock, is ``study.runs.runfolder``'s ``StudyRun``;
``docs/results.md`` says how the studies use them.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import importlib.metadata
import io
import json
import math
import os
import pathlib
import secrets
import zipfile
from collections.abc import Mapping
from typing import Any, NamedTuple

import numpy as np

RECORD_ENTRY = "__record__"  # the npz member that holds a record's JSON header
RECORD_FORMAT = 1


class ResultsError(ValueError):
    """A saved result cannot be used as asked (one-line message naming the file or folder)."""


# --- JSON --------------------------------------------------------------------------------


def to_jsonable(obj: Any) -> Any:
    """``obj`` as plain JSON values: non-finite floats -> ``None``, NumPy scalars and arrays ->
    numbers and (nested) lists, tuples -> lists, paths -> strings, dataclasses and
    NamedTuples -> dicts. Complex numbers are refused (store them in arrays)."""
    if obj is None or isinstance(obj, (bool, str)):
        return obj
    if isinstance(obj, np.bool_):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        return float(obj) if math.isfinite(obj) else None
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist())
    if isinstance(obj, pathlib.PurePath):
        return str(obj)
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return to_jsonable(dataclasses.asdict(obj))
    if isinstance(obj, tuple) and hasattr(obj, "_asdict"):
        return to_jsonable(obj._asdict())
    if isinstance(obj, Mapping):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if hasattr(obj, "__array__") and hasattr(obj, "shape"):  # a JAX array
        return to_jsonable(np.asarray(obj))
    raise TypeError(f"cannot write {type(obj).__name__} as JSON: {obj!r}")


def strict_json_dumps(obj: Any, *, indent: int | None = 1, sort_keys: bool = False) -> str:
    """Standard JSON text of ``obj`` (``to_jsonable`` first; ``allow_nan=False`` as the guard)."""
    return json.dumps(to_jsonable(obj), indent=indent, sort_keys=sort_keys, allow_nan=False)


def _canonical(obj: Any) -> Any:
    # Numbers compare by value (6 and 6.0 give one key); booleans stay booleans.
    if isinstance(obj, bool) or obj is None or isinstance(obj, str):
        return obj
    if isinstance(obj, float):
        return int(obj) if obj.is_integer() and abs(obj) < 2**53 else obj
    if isinstance(obj, dict):
        return {k: _canonical(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_canonical(v) for v in obj]
    return obj


def canonical_json(obj: Any) -> str:
    """Compact, key-sorted strict JSON with integral floats written as integers: equal
    settings give equal text."""
    return json.dumps(_canonical(to_jsonable(obj)), sort_keys=True, separators=(",", ":"), allow_nan=False)


# --- settings and keys ------------------------------------------------------------------


# Read once, as the study tools load: a reinstall under a running study does not restamp its
# later records with a version whose code it is not running.
_VERSION = importlib.metadata.version("armimp_jax")


def package_version() -> str:
    """The armimp_jax version this process loaded (``pyproject.toml``'s, from the metadata)."""
    return _VERSION


def stamped(settings: Mapping) -> dict:
    """``settings`` as plain JSON values with the package version added (key ``armimp_jax``)
    unless it names one already: the form that is saved next to a result."""
    out = to_jsonable(dict(settings))
    out.setdefault("armimp_jax", package_version())
    return out


def settings_key(settings: Mapping) -> str:
    """SHA-256 (hex) of the canonical JSON of ``stamped(settings)``: equal for equal settings
    (numbers by value, dict order ignored), different when any value or the package version
    differs."""
    return hashlib.sha256(canonical_json(stamped(settings)).encode()).hexdigest()


def _flatten(obj: Any, prefix: str = "") -> dict[str, Any]:
    if isinstance(obj, dict):
        out: dict[str, Any] = {}
        for k, v in obj.items():
            out.update(_flatten(v, f"{prefix}.{k}" if prefix else str(k)))
        return out
    return {prefix: obj}


def _show(value: Any) -> str:
    if value is _MISSING:
        return "(unset)"
    if isinstance(value, list):
        return "[" + ",".join(_show(v) for v in value) + "]"
    if isinstance(value, float):
        return f"{value:g}"
    return json.dumps(value) if value is None or isinstance(value, bool) else str(value)


_MISSING = object()


def differences(saved: Mapping, wanted: Mapping) -> list[tuple[str, Any, Any]]:
    """``(dotted name, saved value, wanted value)`` for every setting that differs (numbers
    by value; both stamped with the package version unless they name one)."""
    a = _flatten(_canonical(stamped(saved)))
    b = _flatten(_canonical(stamped(wanted)))
    return [
        (k, a.get(k, _MISSING), b.get(k, _MISSING))
        for k in sorted(a.keys() | b.keys())
        if a.get(k, _MISSING) != b.get(k, _MISSING)
    ]


def describe_difference(saved: Mapping, wanted: Mapping, *, limit: int = 6) -> str:
    """One line: ``seconds=6 (you asked 8), mhat=0.25 (you asked 0.5)`` for the settings that
    differ; ``"no difference"`` if none."""
    diff = differences(saved, wanted)
    if not diff:
        return "no difference"
    parts = [f"{k}={_show(a)} (you asked {_show(b)})" for k, a, b in diff[:limit]]
    if len(diff) > limit:
        parts.append(f"and {len(diff) - limit} more")
    return ", ".join(parts)


# --- atomic writes ------------------------------------------------------------------------


def atomic_write_bytes(path: pathlib.Path | str, data: bytes) -> None:
    """Write ``data`` to ``path`` so that readers (and a crash) see the old file or the new
    one: a temporary file in the same folder, flushed to disk, then renamed over ``path``."""
    path = pathlib.Path(path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp")
    try:
        with open(tmp, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise
    # the rename itself is durable only once the folder is synced (best effort: not on every OS)
    with contextlib.suppress(OSError):
        fd = os.open(path.parent, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def atomic_write_text(path: pathlib.Path | str, text: str) -> None:
    """``atomic_write_bytes`` of UTF-8 text."""
    atomic_write_bytes(path, text.encode())


def atomic_write_json(path: pathlib.Path | str, obj: Any, *, indent: int | None = 1) -> None:
    """``atomic_write_text`` of ``strict_json_dumps(obj, indent=indent)`` (a trailing newline):
    the one writer of every JSON file the study layer saves."""
    atomic_write_text(path, strict_json_dumps(obj, indent=indent) + "\n")


def atomic_write_npz(path: pathlib.Path | str, **arrays) -> pathlib.Path:
    """``atomic_write_bytes`` of ``np.savez`` of NumPy copies of ``arrays`` (uncompressed, no
    pickles): the one writer of every ``.npz`` file the study layer saves. Returns the path."""
    buf = io.BytesIO()
    np.savez(buf, **{k: np.asarray(v) for k, v in arrays.items()})
    atomic_write_bytes(path, buf.getvalue())
    return pathlib.Path(path)


def read_json(path: pathlib.Path | str) -> Any:
    """Parse a JSON file, refusing ``NaN``/``Infinity``; a missing or unreadable file is a
    ``ResultsError`` naming it."""
    path = pathlib.Path(path)

    def refuse(token):
        raise ValueError(f"non-standard JSON constant {token}")

    try:
        return json.loads(path.read_text(), parse_constant=refuse)
    except FileNotFoundError:
        raise ResultsError(f"{path}: no such file") from None
    except (OSError, UnicodeDecodeError, ValueError) as err:
        raise ResultsError(f"{path}: not valid JSON ({_one_line(err)})") from None


# --- checked records ----------------------------------------------------------------------


class Record(NamedTuple):
    """A loaded record: its settings (as saved), their key, free metadata, and named arrays."""

    settings: dict
    key: str
    meta: dict
    arrays: dict


def _digest(header: dict, arrays: Mapping[str, np.ndarray]) -> str:
    h = hashlib.sha256(canonical_json(header).encode())
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        h.update(f"\0{name}\0{a.dtype.str}\0{a.shape}\0".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def save_record(
    path: pathlib.Path | str, *, settings: Mapping, arrays: Mapping | None = None, meta: Mapping | None = None
) -> str:
    """Write one checked record atomically; returns its settings key.

    Args:
        path: the ``.npz`` file to write.
        settings: every value that changes the numbers (stamped with the package version).
        arrays: named arrays (any dtype NumPy saves without pickling; complex included).
        meta: further JSON-able information (scores, timings); covered by the digest too.
    """
    arrays = {k: np.asarray(v) for k, v in (arrays or {}).items()}
    if RECORD_ENTRY in arrays:
        raise ValueError(f"array name {RECORD_ENTRY!r} is reserved")
    for name, a in arrays.items():
        if a.dtype == object:
            raise ValueError(f"array {name!r} has dtype object: records hold plain numbers and strings")
    stamp = stamped(settings)
    header = dict(format=RECORD_FORMAT, settings=stamp, key=settings_key(stamp), meta=to_jsonable(dict(meta or {})))
    header["digest"] = _digest(header, arrays)
    atomic_write_npz(path, **arrays, **{RECORD_ENTRY: np.array(strict_json_dumps(header, indent=None))})
    return header["key"]


def _one_line(err: BaseException) -> str:
    text = " ".join(str(err).split()) or type(err).__name__
    return text if len(text) <= 160 else text[:157] + "..."


def load_record(path: pathlib.Path | str, *, settings: Mapping | None = None) -> Record:
    """Read and check a record written by ``save_record``.

    Raises ``ResultsError`` naming ``path`` when the file is missing, truncated or not a
    record, when its digest does not match its contents (altered after writing), when its
    key does not match its own settings, or, with ``settings`` given, when it was made with
    other settings (the message lists the differences).
    """
    path = pathlib.Path(path)
    if not path.exists():
        raise ResultsError(f"{path}: no such file")
    try:
        # our own handle: np.load leaves its file open when the zip directory is torn
        with open(path, "rb") as fh, np.load(fh, allow_pickle=False) as data:
            if RECORD_ENTRY not in data.files:
                raise ResultsError(f"{path}: not a results record (no {RECORD_ENTRY} entry)")
            header = json.loads(str(data[RECORD_ENTRY][()]))
            arrays = {k: data[k] for k in data.files if k != RECORD_ENTRY}
    except ResultsError:
        raise
    except (OSError, ValueError, EOFError, KeyError, TypeError, AttributeError, zipfile.BadZipFile) as err:
        # (TypeError/AttributeError: np.load found a bare .npy array, not an archive)
        raise ResultsError(f"{path}: unreadable, truncated or not an npz file ({_one_line(err)})") from None
    if not isinstance(header, dict) or not {"settings", "key", "meta", "digest"} <= header.keys():
        raise ResultsError(f"{path}: not a results record (header incomplete)")
    digest = header.pop("digest")
    if _digest(header, arrays) != digest:
        raise ResultsError(f"{path}: checksum mismatch: its numbers or settings were altered after it was written")
    if settings_key(header["settings"]) != header["key"]:
        raise ResultsError(f"{path}: its key does not match its settings (written by another armimp_jax?)")
    if settings is not None and settings_key(settings) != header["key"]:
        raise ResultsError(
            f"{path}: made with other settings: {describe_difference(header['settings'], stamped(settings))}"
        )
    return Record(header["settings"], header["key"], header["meta"], arrays)
