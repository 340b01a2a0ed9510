"""Measured recordings: read and check a lab's CSV or NPZ, estimate and fit, write the results.

A recording holds six channels sampled at one rate ``fs`` [Hz], all in one Cartesian frame:

- ``f_delta_x``, ``f_delta_y``: the perturbation force [N] (the estimator's inputs);
- ``x``, ``y``: the hand (= handle) position [m];
- ``fh_x``, ``fh_y``: the force [N] applied TO the hand by the handle (spec section 2:
  ``F_h = M_h xdd + B_h xd + K_h (x - x0)``); a transducer that reads the force the hand
  exerts on the handle gives ``-F_h``.

CSV: a header row naming the columns (leading ``#`` comment lines are skipped; the
delimiter is ``,``, ``;`` or a tab, read from the header), one sample per row; other
columns are ignored. NPZ: the six names as 1-D arrays, or ``f_delta``, ``x``, ``fh`` as
``(N, 2)`` arrays. ``columns`` maps the standard names to the file's own. Every problem is
a ``RecordingError`` with a one-line message, raised before any computation.

Outputs are written atomically (a temporary file in the same folder, then ``os.replace``);
JSON is strict (non-finite numbers become ``null``).
"""

from __future__ import annotations

import csv
import difflib
import io
import json
import math
import os
import pathlib
import tempfile
import zipfile

import numpy as np

COLUMNS = ("f_delta_x", "f_delta_y", "x", "y", "fh_x", "fh_y")
GROUPS = {"f_delta": ("f_delta_x", "f_delta_y"), "x": ("x", "y"), "fh": ("fh_x", "fh_y")}
OUTPUTS = {"x": ("x", "y"), "fh": ("fh_x", "fh_y")}  # output channels' names, per estimate field
ELEMENTS = ((0, 0), (0, 1), (1, 0), (1, 1))
AXES = ("x", "y")


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


def _check_mapping(columns) -> dict[str, str]:
    columns = dict(columns or {})
    unknown = [k for k in columns if k not in COLUMNS]
    if unknown:
        raise RecordingError(
            f"unknown standard column(s) {', '.join(map(repr, unknown))}; they are {', '.join(COLUMNS)}"
        )
    return columns


def _missing_message(path, missing, found, used=()) -> str:
    parts = []
    spare = [name for name in found if name not in used]  # names already taken are no hint
    for std, name in missing:
        hint = difflib.get_close_matches(name, spare, n=1)
        alias = "" if std == name else f" (for {std})"
        parts.append(f"{name!r}{alias}" + (f" (did you mean {hint[0]!r}?)" if hint else ""))
    shown = ", ".join(map(repr, found[:12])) + (", ..." if len(found) > 12 else "")
    return (
        f"{path}: missing column(s) {', '.join(parts)}; found {shown or 'none'}; "
        "name the file's columns with columns= (--columns STANDARD=NAME,...)"
    )


def _finite_or_raise(values: np.ndarray, where) -> None:
    bad = np.flatnonzero(~np.isfinite(values))
    if bad.size:
        raise RecordingError(f"{where(int(bad[0]))}: {float(values[bad[0]])} is not finite (NaN or inf)")


def _read_csv(path: pathlib.Path, columns: dict[str, str]) -> dict[str, np.ndarray]:
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
    wanted = [(std, columns.get(std, std)) for std in COLUMNS]
    missing = [(std, name) for std, name in wanted if name not in header]
    if missing:
        raise RecordingError(_missing_message(path, missing, header, [n for _, n in wanted]))
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
    return out


def _read_npz(path: pathlib.Path, columns: dict[str, str]) -> dict[str, np.ndarray]:
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
    names = {std: columns.get(std, std) for std in COLUMNS}
    by_column = [n for n in names.values() if n in arrays and np.ndim(arrays[n]) == 1]
    grouped = all(g in arrays for g in GROUPS) and not by_column
    if grouped:
        chans = {}
        for group, stds in GROUPS.items():
            a = arrays[group]
            if a.ndim != 2 or a.shape[1] != 2:
                raise RecordingError(f"{path}: array {group!r} must have shape (N, 2), got {a.shape}")
            for c, std in enumerate(stds):
                chans[std] = (f"{group}[:, {c}]", a[:, c])
    else:
        missing = [(std, n) for std, n in names.items() if n not in arrays]
        if missing:
            raise RecordingError(
                _missing_message(path, missing, list(arrays), names.values()).replace("column(s)", "array(s)")
                + " (or give f_delta, x, fh as (N, 2) arrays)"
            )
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
    return out


def load_recording(path, *, columns=None) -> dict[str, np.ndarray]:
    """Read and check a recording (CSV or NPZ, chosen by the ``.npz`` suffix).

    Args:
        path: the file.
        columns: ``{standard name: the file's name}`` for columns named otherwise (the
            standard names are ``COLUMNS``); unmapped columns keep their standard names.

    Returns ``{"f_delta": (N, 2), "x": (N, 2), "fh": (N, 2)}`` float64 NumPy arrays
    (``[:, 0]`` the x axis, ``[:, 1]`` the y axis), ready for ``estimate``.

    Raises ``RecordingError`` (a ``ValueError``) with one line naming the file and, where
    it applies, the column and row: unreadable file, missing or misnamed columns,
    non-numeric or empty cells, NaN or inf, unequal lengths, no data.
    """
    path = pathlib.Path(path)
    columns = _check_mapping(columns)
    if not path.is_file():
        why = "is a folder" if path.is_dir() else "does not exist"
        raise RecordingError(f"cannot read {path}: it {why}")
    try:
        chans = _read_npz(path, columns) if path.suffix.lower() == ".npz" else _read_csv(path, columns)
    except OSError as err:
        raise RecordingError(f"cannot read {path}: {err.strerror or err}") from None
    n = len(chans[COLUMNS[0]])
    if n == 0:
        raise RecordingError(f"{path}: the recording holds no samples")
    return {group: np.stack([chans[a], chans[b]], axis=1) for group, (a, b) in GROUPS.items()}


def _jsonable(obj):
    """NumPy/JAX values to plain Python; non-finite floats to ``None`` (strict JSON)."""
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, (str, bool)) or obj is None:
        return obj
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if hasattr(obj, "shape") and np.ndim(obj) > 0:
        return _jsonable(np.asarray(obj).tolist())
    value = float(np.asarray(obj))
    return value if math.isfinite(value) else None


def write_atomic(path, write) -> pathlib.Path:
    """Write ``path`` by calling ``write(binary_file)`` on a temporary file in the same folder,
    then ``os.replace``: readers never see a half-written file."""
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            write(fh)
        os.replace(tmp, path)
    except BaseException:
        os.unlink(tmp)
        raise
    return path


def write_json(path, obj) -> pathlib.Path:
    """Strict JSON (``null`` for NaN and inf), written atomically."""
    text = json.dumps(_jsonable(obj), indent=2, allow_nan=False) + "\n"
    return write_atomic(path, lambda fh: fh.write(text.encode()))


def write_npz(path, **arrays) -> pathlib.Path:
    """``np.savez`` of NumPy copies of ``arrays``, written atomically."""
    host = {k: np.asarray(v) for k, v in arrays.items()}
    return write_atomic(path, lambda fh: np.savez(fh, **host))


def _save_figure(fig, path) -> pathlib.Path:
    buf = io.BytesIO()
    fig.savefig(buf, format=pathlib.Path(path).suffix[1:], dpi=110)
    return write_atomic(path, lambda fh: fh.write(buf.getvalue()))


def bode_figure(f, z, z_fit):
    """Magnitude [N/m] and continuous phase [deg] of the four elements of ``z`` ``(F, 2, 2)``
    (estimate) and ``z_fit`` (fitted model) against ``f`` [Hz]: a matplotlib ``Figure``."""
    from matplotlib.figure import Figure  # no pyplot: no global figure state

    f, z, z_fit = (np.asarray(a) for a in (f, z, z_fit))
    fig = Figure(figsize=(15, 6.5), layout="constrained")
    axes = fig.subplots(2, 4, sharex=True)
    for col, (i, j) in enumerate(ELEMENTS):
        name = f"$Z_{{{AXES[i]}{AXES[j]}}}$ ($F_{{h,{AXES[i]}}}$ per ${AXES[j]}$)"
        for data, style, label in ((z, "-", "estimate $\\hat Z$"), (z_fit, "k--", "fitted $M s^2 + B s + K$")):
            axes[0, col].loglog(f, np.abs(data[:, i, j]), style, label=label)
            axes[1, col].semilogx(f, np.degrees(np.unwrap(np.angle(data[:, i, j]))), style)
        axes[0, col].set_title(name)
        axes[1, col].set_xlabel("frequency [Hz]")
    axes[0, 0].set_ylabel("magnitude [N/m]")
    axes[1, 0].set_ylabel("phase [deg] (unwrapped)")
    axes[0, 0].legend(fontsize=8)
    return fig


def coherence_figure(est):
    """Multiple coherences of the four outputs (and the inputs' ordinary coherence), and
    partial coherences of the position and force outputs, against ``f`` [Hz]: a ``Figure``."""
    from matplotlib.figure import Figure

    f = np.asarray(est.f)
    fig = Figure(figsize=(15, 4.5), layout="constrained")
    axes = fig.subplots(1, 3, sharey=True)
    for field, names in OUTPUTS.items():
        mult = np.asarray(getattr(est, f"coh_multiple_{field}"))
        for k, name in enumerate(names):
            axes[0].semilogx(f, mult[:, k], label=name)
    axes[0].semilogx(f, np.asarray(est.coh_inputs), "k:", label="inputs (ordinary)")
    axes[0].set_title("multiple coherence (both inputs)")
    for ax, (field, names) in zip(axes[1:], OUTPUTS.items()):
        part = np.asarray(getattr(est, f"coh_partial_{field}"))
        for k, name in enumerate(names):
            for j, inp in enumerate(("f_delta_x", "f_delta_y")):
                ax.semilogx(f, part[:, k, j], label=f"{name} | {inp}")
        ax.set_title(f"partial coherence, {'position' if field == 'x' else 'force'} outputs")
    axes[0].set_ylabel("coherence [-]")
    for ax in axes:
        ax.set_xlabel("frequency [Hz]")
        ax.set_ylim(0.0, 1.05)
        ax.legend(fontsize=8)
    return fig


def _summary(f, c) -> dict:
    f, c = np.asarray(f), np.asarray(c)
    k = int(np.nanargmin(c)) if np.any(np.isfinite(c)) else 0
    return {
        "min": c[k],
        "f_at_min_hz": f[k],
        "mean": np.mean(c),
        "median": np.median(c),
        "fraction_above_0_9": np.mean(c > 0.9),
    }


def coherence_summary(est) -> dict:
    """Min (and where), mean, median and fraction above 0.9 of each output's multiple
    coherence over the band, and the largest ordinary coherence of the two inputs."""
    out = {}
    for field, names in OUTPUTS.items():
        mult = np.asarray(getattr(est, f"coh_multiple_{field}"))
        out[f"multiple_{field}"] = {name: _summary(est.f, mult[:, k]) for k, name in enumerate(names)}
    ci = np.asarray(est.coh_inputs)
    out["inputs_max"] = np.max(ci)
    out["inputs_f_at_max_hz"] = np.asarray(est.f)[int(np.argmax(ci))]
    return out


def analyse(rec: dict, *, fs: float, nperseg: int, noverlap: int, nfft: int | None, window, fmax: float, weights: str):
    """Estimate ``Z`` (``estimate``) and fit ``M, B, K`` (``fit_impedance``) for a loaded
    recording; returns ``(Estimate, ImpedanceFit)``. Needs float64 switched on; the
    settings must be valid (``check_welch``) and ``window`` a name or tuple."""
    import jax

    from .._estimation.fit import fit_impedance
    from .._estimation.welch import estimate

    def run(f_delta, x, fh):
        est = estimate(f_delta, x, fh, fs=fs, nperseg=nperseg, noverlap=noverlap, fmax=fmax, window=window, nfft=nfft)
        return est, fit_impedance(est, weights=weights)

    # One compiled program: op by op, the first call would compile every small op (~10x slower).
    return jax.jit(run)(rec["f_delta"], rec["x"], rec["fh"])


def write_results(out_dir, est, fit, *, settings: dict, record: dict) -> list[pathlib.Path]:
    """Write ``estimate.json``, ``estimate.npz``, ``bode.png`` and ``coherence.png`` under
    ``out_dir`` (each atomically); returns their paths."""
    import scipy.stats

    out_dir = pathlib.Path(out_dir)
    dof = np.asarray(fit.dof)
    result = {
        "settings": settings,
        "record": record,
        "units": {"f": "Hz", "mass": "kg", "damping": "N s/m", "stiffness": "N/m", "Z": "N/m", "vaf": "%"},
        "convention": (
            "Z = T R^-1 [N/m], force applied to the hand per hand displacement, indexed [output, input] "
            "(row: force axis, column: displacement axis), axes of the recording's frame; "
            "fitted Z(f) = K - w^2 M + j w B, w = 2 pi f; a 95% interval is value +- t95 * se"
        ),
        "mass": fit.mass,
        "mass_se": fit.mass_se,
        "damping": fit.damping,
        "damping_se": fit.damping_se,
        "stiffness": fit.stiffness,
        "stiffness_se": fit.stiffness_se,
        "dof": dof,
        "t95": scipy.stats.t.ppf(0.975, dof),
        "vaf": {"overall": fit.vaf_overall, "per_element": fit.vaf},
        "coherence": coherence_summary(est),
    }
    paths = [
        write_json(out_dir / "estimate.json", result),
        write_npz(out_dir / "estimate.npz", **est._asdict(), Z_fit=fit.impedance(est.f)),
        _save_figure(bode_figure(est.f, est.Z, fit.impedance(est.f)), out_dir / "bode.png"),
        _save_figure(coherence_figure(est), out_dir / "coherence.png"),
    ]
    return paths
