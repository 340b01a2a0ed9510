"""Measured recordings: read and check a lab's CSV, NPZ or MAT-file.

A recording holds six channels sampled at one rate ``fs`` [Hz], all in one Cartesian frame:

- ``f_delta_x``, ``f_delta_y``: the perturbation force [N] (the estimator's inputs);
- ``x``, ``y``: the hand (= handle) position [m];
- ``fh_x``, ``fh_y``: the force [N] applied TO the hand by the handle (docs/model.md section 3:
  ``F_h = M_h xdd + B_h xd + K_h (x - x0)``); a transducer that reads the force the hand
  exerts on the handle gives ``-F_h``.

An optional time column [s] (``time``, ``time_s`` or ``timestamp`` in any case, ``t``, or the
name ``columns`` maps ``time`` to) is read too, for ``timestamp_warnings``: what its steps
say against the sample rate given.

CSV: a header row naming the columns (leading ``#`` comment lines are skipped; the
delimiter is ``,``, ``;`` or a tab, read from the header), one sample per row; other
columns are ignored. NPZ and MAT (MATLAB up to v7, ``scipy.io.loadmat``; v7.3 is HDF5 and
refused with how to re-save it): the six names as vectors, or ``f_delta``, ``x``, ``fh`` as
``(N, 2)`` arrays. ``columns`` maps the standard names to the file's own. Every problem is
a ``RecordingError`` with a one-line message, raised before any computation.

What is done with a loaded recording: ``study.recording.estimate_recording`` (the Welch route) and
``study.recording.identify_recording`` (the model route). ``load_ensemble`` reads one file per repetition
of a reach into an ``Ensemble`` (``estimate_ensemble``'s input).
"""

from __future__ import annotations

import csv
import difflib
import pathlib
import zipfile

import numpy as np

from ..._estimation.ensemble import Ensemble

COLUMNS = ("f_delta_x", "f_delta_y", "x", "y", "fh_x", "fh_y")
GROUPS = {"f_delta": ("f_delta_x", "f_delta_y"), "x": ("x", "y"), "fh": ("fh_x", "fh_y")}
TIME = "time"  # the optional time column's standard name [s]
TIME_NAMES = ("time", "time_s", "timestamp")  # a column read as the time unless mapped (any case; and "t")
RATE_TOLERANCE = 0.01  # the time column's rate and the one given differ by more than this share: a warning
UNEVEN = 0.5  # a time step this far from the median step (as its share): samples dropped or repeated


class RecordingError(ValueError):
    """A recording that cannot be used, with a one-line message saying why and where."""


def parse_columns(text: str) -> dict[str, str]:
    """``"fh_x=Fx,fh_y=Fy"`` -> ``{"fh_x": "Fx", "fh_y": "Fy"}`` (standard name = file's name)."""
    mapping = {}
    for item in filter(None, (part.strip() for part in text.split(","))):
        std, sep, name = (s.strip() for s in item.partition("="))
        if not sep or not std or not name:
            raise RecordingError(f"column mapping {item!r} is not STANDARD=NAME (e.g. fh_x=Fx)")
        mapping[std] = name
    return _check_mapping(mapping)


def _check_mapping(columns, groups=GROUPS) -> dict[str, str]:
    columns = dict(columns or {})
    names = [c for pair in groups.values() for c in pair]
    unknown = [k for k in columns if k not in (*names, TIME)]
    if unknown:
        raise RecordingError(
            f"unknown standard column(s) {', '.join(map(repr, unknown))}; they are {', '.join(names)} "
            f"(and {TIME}, optional)"
        )
    return columns


def _time_name(names, columns: dict[str, str]) -> tuple[str | None, bool]:
    """The time column's name among ``names`` and whether it was mapped (then it is required)."""
    if TIME in columns:
        return columns[TIME], True
    found = (n for n in names if str(n).strip().lower() in TIME_NAMES or str(n).strip() == "t")  # "T": a torque?
    return next(found, None), False


def _optional_time(values, n: int):
    """A found (not mapped) time column: its values, or ``None`` where they are no clock."""
    try:
        t = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError):
        return None
    return t if t.shape == (n,) and np.all(np.isfinite(t)) else None


class MissingColumnsError(RecordingError):
    """Columns (an NPZ's or MAT-file's arrays) that the recording lacks under the names asked for.

    ``str(err)`` tells a library user how to name them (``columns=``); ``err.for_option("--columns")``
    is the same line for a command-line tool, naming its own option instead.
    """

    def __init__(self, path, missing, found, used=(), *, noun: str = "column", tail: str = ""):
        parts, example = [], []
        spare = [name for name in found if name not in used]  # names already taken are no hint
        for std, name in missing:
            hint = difflib.get_close_matches(name, spare, n=1)
            alias = "" if std == name else f" (for {std})"
            parts.append(f"{name!r}{alias}" + (f" (did you mean {hint[0]!r}?)" if hint else ""))
            if hint:
                example.append((std, hint[0]))
        shown = ", ".join(map(repr, found[:12])) + (", ..." if len(found) > 12 else "")
        self.head = f"{path}: missing {noun}(s) {', '.join(parts)}; found {shown or 'none'}; name the file's {noun}s"
        self.example = example or [(missing[0][0], "NAME")]  # the hints as a mapping, or its shape
        self.tail = tail
        super().__init__(self.for_option(None))

    def for_option(self, option: str | None) -> str:
        """The message naming ``option`` (e.g. ``"--columns"``, which takes ``STANDARD=NAME,...``),
        or with ``None`` the library's ``columns=`` mapping."""
        if option is None:
            how = "columns={" + ", ".join(f"{s!r}: {n!r}" for s, n in self.example) + "}"
        else:
            how = f"{option} " + ",".join(f"{s}={n}" for s, n in self.example)
        return f"{self.head} with {how}{self.tail}"


def _finite_or_raise(values: np.ndarray, where) -> None:
    bad = np.flatnonzero(~np.isfinite(values))
    if bad.size:
        raise RecordingError(f"{where(int(bad[0]))}: {float(values[bad[0]])} is not finite (NaN or inf)")


def _read_csv(path: pathlib.Path, columns: dict[str, str], groups=GROUPS) -> dict[str, np.ndarray]:
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError:
        raise RecordingError(f"cannot read {path}: not a UTF-8 text (CSV) file") from None
    lines = text.splitlines()
    start = 0
    while start < len(lines) and (not lines[start].strip() or lines[start].lstrip().startswith("#")):
        start += 1
    if start == len(lines):
        raise RecordingError(f"{path}: no header row (the file is empty or only comments)")
    header_line = lines[start]
    delimiter = next((d for d in (",", ";", "\t") if d in header_line), ",")
    try:
        rows = list(csv.reader(lines[start:], delimiter=delimiter))
    except csv.Error as err:
        raise RecordingError(f"cannot parse {path} as CSV: {err}") from None
    header = [h.strip() for h in rows[0]]
    time_name, mapped = _time_name(header, columns)
    names = [c for pair in groups.values() for c in pair]
    wanted = [(std, columns.get(std, std)) for std in names] + ([(TIME, time_name)] if mapped else [])
    missing = [(std, name) for std, name in wanted if name not in header]
    if missing:
        raise MissingColumnsError(path, missing, header, [n for _, n in wanted])
    twice = [name for _, name in wanted if header.count(name) > 1]
    if twice:
        raise RecordingError(f"{path}: column {twice[0]!r} appears more than once in the header")
    data = rows[1:]
    while data and not any(cell.strip() for cell in data[-1]):
        data.pop()  # trailing blank lines
    if not data:
        raise RecordingError(f"{path}: the header is not followed by any data rows")

    def where(k: int, name: str) -> str:  # data row k (0-based) of column name
        return f"{path}: row {k + 1} (line {start + k + 2}), column {name!r}"

    cells, lengths = {}, {}
    for std, name in wanted:
        i = header.index(name)
        col = [row[i].strip() if i < len(row) else "" for row in data]
        n = len(col)
        while n and not col[n - 1]:
            n -= 1  # a column that ends early: the lengths check below names it
        cells[std], lengths[name] = col[:n], n
    if len(set(lengths.values())) > 1:
        described = ", ".join(f"{name} {n}" for name, n in lengths.items())
        raise RecordingError(f"{path}: columns have unequal lengths (values per column: {described})")
    out = {}
    for std, name in wanted:
        col = cells[std]
        try:
            values = np.asarray(col, dtype=np.float64)
        except ValueError:  # parse cell by cell to name the first bad one
            values = np.empty(len(col))
            for k, cell in enumerate(col):
                try:
                    values[k] = float(cell)
                except ValueError:
                    what = " is empty" if not cell else f": {cell!r} is not a number"
                    raise RecordingError(f"{where(k, name)}{what}") from None
        _finite_or_raise(values, lambda k, name=name: where(k, name))
        out[std] = values
    if time_name is not None and not mapped:
        i = header.index(time_name)
        found = _optional_time([row[i].strip() if i < len(row) else "" for row in data], len(out[names[0]]))
        if found is not None:
            out[TIME] = found
    return out


def _read_npz(path: pathlib.Path, columns: dict[str, str], groups=GROUPS) -> dict[str, np.ndarray]:
    try:
        # our own handle: np.load leaks its own when the zip is corrupt
        with open(path, "rb") as fh:
            if fh.read(4) != b"PK\x03\x04":
                raise RecordingError(f"cannot read {path} as NPZ: not a zip archive (as numpy.savez writes)")
            fh.seek(0)
            with np.load(fh, allow_pickle=False) as npz:
                arrays = {k: npz[k] for k in npz.files}
    except (ValueError, OSError, zipfile.BadZipFile, EOFError) as err:
        raise RecordingError(f"cannot read {path} as NPZ: {err}") from None
    return _from_arrays(path, arrays, columns, groups)


V73 = "re-save it in MATLAB with save(file, ..., '-v7') (v7.3 MAT-files are HDF5, which scipy.io cannot read)"


def _read_mat(path: pathlib.Path, columns: dict[str, str], groups=GROUPS) -> dict[str, np.ndarray]:
    import scipy.io

    with open(path, "rb") as fh:
        head = fh.read(520)
    if head[:10] == b"MATLAB 7.3" or head[512:520] == b"\x89HDF\r\n\x1a\n":
        raise RecordingError(f"{path} is a MATLAB v7.3 MAT-file: {V73}")
    try:
        raw = scipy.io.loadmat(path)
    except NotImplementedError:  # scipy's answer to HDF5-based files
        raise RecordingError(f"{path} is a MATLAB v7.3 MAT-file: {V73}") from None
    except Exception as err:  # scipy.io raises ValueError, TypeError, EOFError, ... on a bad file
        raise RecordingError(
            f"cannot read {path} as a MAT-file: {str(err).splitlines()[0] if str(err) else err!r}"
        ) from None
    arrays = {}
    for name, a in raw.items():
        if name.startswith("__"):
            continue  # loadmat's header, version and globals
        a = np.asarray(a)
        if a.ndim == 2 and 1 in a.shape:
            a = a.reshape(-1)  # a MATLAB vector is a 1 x N or N x 1 matrix
        arrays[name] = a
    return _from_arrays(path, arrays, columns, groups)


def _from_arrays(path: pathlib.Path, arrays: dict, columns: dict[str, str], groups=GROUPS) -> dict[str, np.ndarray]:
    """The channels of ``groups`` (default the six) from an NPZ's or MAT-file's named arrays, checked."""
    names = {std: columns.get(std, std) for pair in groups.values() for std in pair}
    by_column = [n for n in names.values() if n in arrays and np.ndim(arrays[n]) == 1]
    grouped = all(g in arrays for g in groups) and not by_column
    if grouped:
        chans = {}
        for group, stds in groups.items():
            a = arrays[group]
            if a.ndim != 2 or a.shape[1] != 2:
                raise RecordingError(f"{path}: array {group!r} must have shape (N, 2), got {a.shape}")
            for c, std in enumerate(stds):
                chans[std] = (f"{group}[:, {c}]", a[:, c])
    else:
        missing = [(std, n) for std, n in names.items() if n not in arrays]
        if missing:
            tail = f" (or give {', '.join(groups)} as (N, 2) arrays)"
            raise MissingColumnsError(path, missing, list(arrays), names.values(), noun="array", tail=tail)
        chans = {std: (n, arrays[n]) for std, n in names.items()}
        for label, a in chans.values():
            if a.ndim != 1:
                raise RecordingError(f"{path}: array {label!r} must be 1-D, got shape {a.shape}")
    for label, a in chans.values():
        if a.dtype == np.bool_ or not (np.issubdtype(a.dtype, np.integer) or np.issubdtype(a.dtype, np.floating)):
            raise RecordingError(f"{path}: array {label!r} is not real numbers (dtype {a.dtype})")
    lengths = {label: len(a) for label, a in chans.values()}
    if len(set(lengths.values())) > 1:
        described = ", ".join(f"{label} {n}" for label, n in lengths.items())
        raise RecordingError(f"{path}: arrays have unequal lengths (samples per channel: {described})")
    out = {}
    for std, (label, a) in chans.items():
        values = a.astype(np.float64)
        _finite_or_raise(values, lambda k, label=label: f"{path}: array {label!r}, index {k}")
        out[std] = values
    return out | _array_time(path, arrays, columns, len(next(iter(out.values()))))


def _array_time(path, arrays: dict, columns: dict[str, str], n: int) -> dict:
    """``{"time": (n,)}`` from an NPZ's or MAT-file's arrays where it has a time array, else ``{}``;
    a mapped one must be there, a vector of ``n`` finite numbers."""
    name, mapped = _time_name(list(arrays), columns)
    if name is None:
        return {}
    if name not in arrays:
        raise MissingColumnsError(path, [(TIME, name)], list(arrays), noun="array")
    t = _optional_time(arrays[name], n) if np.ndim(arrays[name]) == 1 else None
    if t is None and mapped:
        raise RecordingError(f"{path}: array {name!r} (the time) must be {n} finite numbers, like the channels")
    return {} if t is None else {TIME: t}


def load_recording(path, *, columns=None, groups=None) -> dict[str, np.ndarray]:
    """Read and check a recording: NPZ (suffix ``.npz``), MAT-file (``.mat``) or else CSV.

    Args:
        path: the file.
        columns: ``{standard name: the file's name}`` for columns named otherwise (the
            standard names are ``COLUMNS``); unmapped columns keep their standard names.
        groups: ``{name: (x column, y column)}`` of another kind of file (a robot-alone record's
            command, known loads: ``study.recording.calibration_files``); default ``GROUPS``, the six.

    Returns ``{"f_delta": (N, 2), "x": (N, 2), "fh": (N, 2)}`` float64 NumPy arrays
    (``[:, 0]`` the x axis, ``[:, 1]`` the y axis), ready for ``estimate``, and ``"time"``
    ``(N,)`` [s] where the file has a time column (module docstring; ``timestamp_warnings``).

    Raises ``RecordingError`` (a ``ValueError``) with one line naming the file and, where
    it applies, the column and row: unreadable file (a v7.3 MAT-file: how to re-save it),
    missing or misnamed columns, non-numeric or empty cells, NaN or inf, unequal lengths,
    no data.
    """
    path, groups = pathlib.Path(path), GROUPS if groups is None else groups
    columns = _check_mapping(columns, groups)
    if not path.is_file():
        why = "is a folder" if path.is_dir() else "does not exist"
        raise RecordingError(f"cannot read {path}: it {why}")
    try:
        read = {".npz": _read_npz, ".mat": _read_mat}.get(path.suffix.lower(), _read_csv)
        chans = read(path, columns, groups)
    except OSError as err:
        raise RecordingError(f"cannot read {path}: {err.strerror or err}") from None
    n = len(chans[next(iter(groups.values()))[0]])
    if n == 0:
        raise RecordingError(f"{path}: the recording holds no samples")
    out = {group: np.stack([chans[a], chans[b]], axis=1) for group, (a, b) in groups.items()}
    return out | ({TIME: chans[TIME]} if TIME in chans else {})


def timestamp_warnings(rec: dict, fs: float) -> list[str]:
    """What a recording's own time column (``rec["time"]`` [s], ``load_recording``'s; none: no
    warning) says against the sample rate ``fs`` [Hz] given, one line each: a rate that differs
    by more than ``RATE_TOLERANCE`` (read in seconds, or in milliseconds where that matches), a
    clock that does not run forward, steps that stray more than ``UNEVEN`` from the median."""
    t = rec.get(TIME)
    if t is None or len(t) < 2:
        return []
    steps = np.diff(np.asarray(t, dtype=float))
    step = float(np.median(steps))
    if not step > 0:
        return [f"the file's time column does not run forward (median step {step:g}): check it and fs {fs:g} Hz"]
    out = []
    if not any(abs(rate - fs) <= RATE_TOLERANCE * fs for rate in (1.0 / step, 1e3 / step)):
        out.append(
            f"the file's time column steps by {step:.6g} s (median): a rate of {1.0 / step:.6g} Hz, but fs is "
            f"{fs:g} Hz; a wrong rate scales the classical M by (true / given)^2 and B by true / given, and "
            "moves the band fitted: give the file's rate"
        )
    if np.max(np.abs(steps - step)) > UNEVEN * step:
        out.append(
            f"the file's time column is uneven: steps from {np.min(steps):.6g} to {np.max(steps):.6g} (median "
            f"{step:.6g}): samples dropped or repeated; both routes assume one rate throughout"
        )
    return out


def load_ensemble(paths, *, columns=None, period: float | None = None) -> Ensemble:
    """A lab's ensemble: one recording per repetition of one reach (``load_recording``'s formats).

    Args:
        paths: the files, one per repetition, each cut to the same samples around the reach
            (aligned on its onset).
        columns: as ``load_recording``'s, the same for every file.
        period: the sample period [s]; default: from the first file's time column, else 1 ms.

    Refused in one line (``Ensemble``'s rules): no files, repetitions of different lengths, a
    repetition whose path strays from the others' (a reach to another target), and every
    problem of ``load_recording``, naming the file.
    """
    paths = [paths] if isinstance(paths, (str, pathlib.Path)) else list(paths)
    if not paths:
        raise RecordingError("load_ensemble: no files given (one recording per repetition)")
    return Ensemble.from_recordings([load_recording(p, columns=columns) for p in paths], period=period)
