"""Measured recordings: read and check a lab's CSV, NPZ or MAT-file, estimate and fit, write the results.

A recording holds six channels sampled at one rate ``fs`` [Hz], all in one Cartesian frame:

- ``f_delta_x``, ``f_delta_y``: the perturbation force [N] (the estimator's inputs);
- ``x``, ``y``: the hand (= handle) position [m];
- ``fh_x``, ``fh_y``: the force [N] applied TO the hand by the handle (docs/model.md section 3:
  ``F_h = M_h xdd + B_h xd + K_h (x - x0)``); a transducer that reads the force the hand
  exerts on the handle gives ``-F_h``.

CSV: a header row naming the columns (leading ``#`` comment lines are skipped; the
delimiter is ``,``, ``;`` or a tab, read from the header), one sample per row; other
columns are ignored. NPZ and MAT (MATLAB up to v7, ``scipy.io.loadmat``; v7.3 is HDF5 and
refused with how to re-save it): the six names as vectors, or ``f_delta``, ``x``, ``fh`` as
``(N, 2)`` arrays. ``columns`` maps the standard names to the file's own. Every problem is
a ``RecordingError`` with a one-line message, raised before any computation.

Outputs are written atomically (``study.results.atomic_write_*``, ``study.figures.save_figure``);
JSON is strict (non-finite numbers become ``null``).
"""

from __future__ import annotations

import csv
import difflib
import io
import pathlib
import zipfile

import numpy as np

from .._estimation.diagnose import input_coherence_chance
from .figures import save_figure
from .results import atomic_write_bytes, atomic_write_json

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
    return _from_arrays(path, arrays, columns)


V73 = "re-save it in MATLAB with save(file, ..., '-v7') (v7.3 MAT-files are HDF5, which scipy.io cannot read)"


def _read_mat(path: pathlib.Path, columns: dict[str, str]) -> dict[str, np.ndarray]:
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
    return _from_arrays(path, arrays, columns)


def _from_arrays(path: pathlib.Path, arrays: dict[str, np.ndarray], columns: dict[str, str]) -> dict[str, np.ndarray]:
    """The six channels from an NPZ's or MAT-file's named arrays, checked."""
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
    """Read and check a recording: NPZ (suffix ``.npz``), MAT-file (``.mat``) or else CSV.

    Args:
        path: the file.
        columns: ``{standard name: the file's name}`` for columns named otherwise (the
            standard names are ``COLUMNS``); unmapped columns keep their standard names.

    Returns ``{"f_delta": (N, 2), "x": (N, 2), "fh": (N, 2)}`` float64 NumPy arrays
    (``[:, 0]`` the x axis, ``[:, 1]`` the y axis), ready for ``estimate``.

    Raises ``RecordingError`` (a ``ValueError``) with one line naming the file and, where
    it applies, the column and row: unreadable file (a v7.3 MAT-file: how to re-save it),
    missing or misnamed columns, non-numeric or empty cells, NaN or inf, unequal lengths,
    no data.
    """
    path = pathlib.Path(path)
    columns = _check_mapping(columns)
    if not path.is_file():
        why = "is a folder" if path.is_dir() else "does not exist"
        raise RecordingError(f"cannot read {path}: it {why}")
    try:
        read = {".npz": _read_npz, ".mat": _read_mat}.get(path.suffix.lower(), _read_csv)
        chans = read(path, columns)
    except OSError as err:
        raise RecordingError(f"cannot read {path}: {err.strerror or err}") from None
    n = len(chans[COLUMNS[0]])
    if n == 0:
        raise RecordingError(f"{path}: the recording holds no samples")
    return {group: np.stack([chans[a], chans[b]], axis=1) for group, (a, b) in GROUPS.items()}


def write_npz(path, **arrays) -> pathlib.Path:
    """``np.savez`` of NumPy copies of ``arrays``, written atomically."""
    buf = io.BytesIO()
    np.savez(buf, **{k: np.asarray(v) for k, v in arrays.items()})
    atomic_write_bytes(path, buf.getvalue())
    return pathlib.Path(path)


def bode_figure(f, z, z_fit):
    """Magnitude [N/m] and continuous phase [deg] of the four elements of ``z`` ``(F, 2, 2)``
    (estimate) and ``z_fit`` (the fitted model of the record, its acquisition included)
    against ``f`` [Hz]: a matplotlib ``Figure``."""
    from matplotlib.figure import Figure  # no pyplot: no global figure state

    f, z, z_fit = (np.asarray(a) for a in (f, z, z_fit))
    fig = Figure(figsize=(15, 6.5), layout="constrained")
    axes = fig.subplots(2, 4, sharex=True)
    for col, (i, j) in enumerate(ELEMENTS):
        name = f"$Z_{{{AXES[i]}{AXES[j]}}}$ ($F_{{h,{AXES[i]}}}$ per ${AXES[j]}$)"
        for data, style, label in ((z, "-", "estimate $\\hat Z$"), (z_fit, "k--", "fitted model")):
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
    coherence over the band, and the largest ordinary coherence of the two inputs with the
    probability that independent inputs reach it by chance (``input_coherence_chance``)."""
    out = {}
    for field, names in OUTPUTS.items():
        mult = np.asarray(getattr(est, f"coh_multiple_{field}"))
        out[f"multiple_{field}"] = {name: _summary(est.f, mult[:, k]) for k, name in enumerate(names)}
    ci = np.asarray(est.coh_inputs)
    out["inputs_max"] = np.max(ci)
    out["inputs_f_at_max_hz"] = np.asarray(est.f)[int(np.argmax(ci))]
    out["inputs_chance_p"] = input_coherence_chance(est)[1]
    return out


def check_settings(n_samples: int, *, fs: float, nperseg: int, noverlap: int, nfft, window, fmax: float) -> int:
    """Validate the Welch settings for a record of ``n_samples``; return the number of segments
    (``ValueError`` with one line otherwise, before any computation)."""
    from .._estimation.welch import check_welch

    return check_welch(n_samples, fs=fs, nperseg=nperseg, noverlap=noverlap, fmax=fmax, nfft=nfft, window=window)


def analyse(
    rec: dict,
    *,
    fs: float,
    nperseg: int,
    noverlap: int,
    nfft: int | None,
    window,
    fmax: float,
    weights: str,
    acquisition: str = "plain",
    period: float | None = None,
    se: str = "residual",
):
    """Estimate ``Z`` (``estimate``, with its error model) and fit ``M, B, K`` (``fit_impedance``
    with ``weights``, ``acquisition``, ``period`` [s] (default ``1 / fs``) and ``se``) for a
    loaded recording; returns ``(Estimate, ImpedanceFit)``. Needs float64 switched on; the
    settings must be valid (``check_settings``) and ``window`` a name or tuple."""
    import jax

    from .._estimation.fit import fit_impedance
    from .._estimation.welch import estimate

    period = 1.0 / fs if period is None else period

    def run(f_delta, x, fh):
        est = estimate(
            f_delta, x, fh, fs=fs, nperseg=nperseg, noverlap=noverlap, fmax=fmax, window=window, nfft=nfft, errors=True
        )
        return est, fit_impedance(est, weights=weights, acquisition=acquisition, period=period, se=se)

    # One compiled program: op by op, the first call would compile every small op (~10x slower).
    return jax.jit(run)(rec["f_delta"], rec["x"], rec["fh"])


PARAMETERS = (("mass", "kg"), ("damping", "N s/m"), ("stiffness", "N/m"))


def intervals(fit, level: float = 0.95) -> dict:
    """``{name: {"low", "high"}}`` two-sided ``level`` intervals of ``mass``, ``damping``,
    ``stiffness`` (``(2, 2)`` each) and ``delay`` (``ImpedanceFit.interval``)."""
    out = {}
    for name in (*(n for n, _ in PARAMETERS), "delay"):
        low, high = fit.interval(name, level)
        out[name] = {"low": low, "high": high}
    return out


def report_lines(est, fit, *, acquisition: str, warnings: list[str]) -> list[str]:
    """What the script prints: the fit's 95% intervals per element, the fitted delay, the
    lack-of-fit test, the coherence summary and the warnings, one item a line."""
    ci = intervals(fit)
    lines = [
        f"fit: acquisition {acquisition!r}; VAF {float(fit.vaf_overall):.2f} % (variance of Z the model accounts for)"
    ]
    lines.append(
        "95% intervals [low, high] (t quantile of each element's dof), indexed [force axis, displacement axis]:"
    )
    for name, unit in PARAMETERS:
        value = np.asarray(getattr(fit, name))
        lo, hi = ci[name]["low"], ci[name]["high"]
        for i, j in ELEMENTS:
            lines.append(
                f"  {name} {AXES[i]}{AXES[j]} [{unit}]: {value[i, j]:10.4g}   95% [{lo[i, j]:.4g}, {hi[i, j]:.4g}]"
            )
    if acquisition == "delay":
        d, lo, hi = (1e3 * float(np.asarray(v)) for v in (fit.delay, ci["delay"]["low"], ci["delay"]["high"]))
        lines.append(f"  force-channel delay [ms]: {d:.4g}   95% [{lo:.4g}, {hi:.4g}]")
    lof, p = float(np.asarray(fit.lack_of_fit_overall)), float(np.asarray(fit.lack_of_fit_p_overall))
    lines.append(f"lack of fit: residuals / predicted variance {lof:.3g} (about 1 when the model fits), p = {p:.3g}")
    summary = coherence_summary(est)
    for field, names in OUTPUTS.items():
        for name in names:
            c = summary[f"multiple_{field}"][name]
            lines.append(
                f"coherence {name}: min {c['min']:.3f} at {c['f_at_min_hz']:.3g} Hz, median {c['median']:.3f}, "
                f"{100 * c['fraction_above_0_9']:.0f}% of bins above 0.9"
            )
    lines.append(
        f"input coherence: max {summary['inputs_max']:.3f} at {summary['inputs_f_at_max_hz']:.3g} Hz (paper's guide "
        f"0.4; independent inputs reach it by chance with p = {summary['inputs_chance_p']:.2g})"
    )
    lines += [f"WARNING: {w}" for w in warnings] or ["no warnings"]
    return lines


def write_results(out_dir, est, fit, *, settings: dict, record: dict, warnings: list[str]) -> list[pathlib.Path]:
    """Write ``estimate.json``, ``estimate.npz``, ``bode.png`` and ``coherence.png`` under
    ``out_dir`` (each atomically); returns their paths."""
    out_dir = pathlib.Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    acq = dict(acquisition=settings.get("acquisition", "plain"), period=settings.get("period_s", 1e-3))
    z_fit = fit.impedance(est.f, **acq)
    result = {
        "settings": settings,
        "record": record,
        "units": {
            "f": "Hz",
            "mass": "kg",
            "damping": "N s/m",
            "stiffness": "N/m",
            "delay": "s",
            "Z": "N/m",
            "vaf": "%",
        },
        "convention": (
            "Z = T R^-1 [N/m], force applied to the hand per hand displacement, indexed [output, input] "
            "(row: force axis, column: displacement axis), axes of the recording's frame; "
            "Z(f) = K - w^2 M + j w B, w = 2 pi f, in the acquisition's model of the record "
            "(docs/estimation.md); a 95% interval is value +- t95 * se, t95 = t_0.975(dof), given as interval_95"
        ),
        **{k: np.asarray(getattr(fit, k)) for k in ("mass", "mass_se", "damping", "damping_se")},
        **{k: np.asarray(getattr(fit, k)) for k in ("stiffness", "stiffness_se", "dof")},
        "t95": _t95(np.asarray(fit.dof)),
        "interval_95": intervals(fit),
        "delay": {"value": np.asarray(fit.delay), "se": np.asarray(fit.delay_se), "dof": np.asarray(fit.delay_dof)},
        "lack_of_fit": {
            "ratio": np.asarray(fit.lack_of_fit_overall),
            "p": np.asarray(fit.lack_of_fit_p_overall),
            "per_element_ratio": np.asarray(fit.lack_of_fit),
            "per_element_p": np.asarray(fit.lack_of_fit_p),
        },
        "vaf": {"overall": np.asarray(fit.vaf_overall), "per_element": np.asarray(fit.vaf)},
        "coherence": coherence_summary(est),
        "warnings": list(warnings),
    }
    est_arrays = {k: v for k, v in est._asdict().items() if k != "error"}
    errors = {f"error_{k}": v for k, v in est.error._asdict().items()} if est.error is not None else {}
    json_path = out_dir / "estimate.json"
    atomic_write_json(json_path, result)
    return [
        json_path,
        write_npz(out_dir / "estimate.npz", **est_arrays, **errors, Z_fit=z_fit),
        save_figure(bode_figure(est.f, est.Z, z_fit), out_dir / "bode.png"),
        save_figure(coherence_figure(est), out_dir / "coherence.png"),
    ]


def _t95(dof):
    import scipy.stats

    return scipy.stats.t.ppf(0.975, np.where(np.isfinite(dof), dof, np.inf))
