"""Tidy tables as pandas DataFrames: the sweep's columns and types, and writing and reading them.

Every table a study writes goes through here: ``table(rows, dtypes)`` builds a DataFrame
(one row per observation; a column's type is declared, floats where none is, so a
column keeps its type whatever values a run happens to hold), ``write_table`` writes it
as CSV (always) and Parquet (when ``pyarrow`` is importable), atomically, and
``read_table`` reads a CSV back into the same DataFrame.

CSV conventions (a sweep's ``trials.csv`` and ``summary.csv`` have kept them since their
first version): comma-separated, ``\\n`` line ends, a header row; an empty cell for an
undefined number (NaN and infinities alike: no ``NaN`` in the files); floats written as
their shortest round-trip text (Python's ``repr``), so every number reads back exactly;
integers without a decimal point; booleans as ``True``/``False``. An empty cell is a
missing value, so a string column holds ``None`` rather than ``""``.

A sweep's tables: ``trials_frame`` (one row per trial: ``trial_columns``, ``TRIAL_DTYPES``)
and ``summary_frame`` (one row per point: ``SUMMARY_DTYPES``); the per-trial numbers are
``METRIC_COLUMNS``.
"""

from __future__ import annotations

import importlib.util
import io
import pathlib
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from ..runs.results import atomic_write_bytes, atomic_write_text

if TYPE_CHECKING:
    from ..schema.points import Point

STRING = "string"  # pandas' string dtype (missing: <NA>, an empty cell)
INTEGER = "int64"
NULLABLE_INTEGER = "Int64"  # an integer setting that may not apply (an empty cell)
FLOAT = "float64"
BOOLEAN = "bool"

ELEMENTS = ("11", "12", "21", "22")  # (2, 2) arrays as columns, [output, input], row-major
FIT_COLUMNS = tuple(f"{p}_{e}{se}" for p in ("M", "B", "K") for se in ("", "_se") for e in ELEMENTS) + tuple(
    f"vaf_{e}" for e in ELEMENTS
)
COH_COLUMNS = tuple(f"coh_{c}_{s}" for c in ("x1", "x2", "fh1", "fh2") for s in ("min", "median"))
# a sweep's per-trial numbers: the statistics of summary.csv are taken over each of these
METRIC_COLUMNS = (
    ("phi_T",)
    + tuple(f"phi_{e}" for e in ELEMENTS)
    + ("rel_error", "coh_min")
    + COH_COLUMNS
    + ("input_coherence_max",)
    + FIT_COLUMNS
    + ("vaf_overall",)
)
# column types of a point's columns (``points.point_columns``; floats where none is named)
POINT_DTYPES = dict(
    controller=STRING,
    friction=STRING,
    arm=STRING,  # a location ("1") or "user-<hash>"
    perturbation_level=NULLABLE_INTEGER,  # none when a peak is given
    acquisition=STRING,
    nperseg=INTEGER,
    noverlap=INTEGER,
    window=STRING,
    nfft=NULLABLE_INTEGER,
)
TRIAL_DTYPES = POINT_DTYPES | dict(
    point_index=INTEGER,
    seed=INTEGER,
    trial_id=STRING,
    base_seed=INTEGER,
    method=STRING,
    substeps=INTEGER,
    diverged=BOOLEAN,
    diverged_at=INTEGER,
)
SUMMARY_DTYPES = POINT_DTYPES | dict(method=STRING, substeps=INTEGER, trials=INTEGER, n=INTEGER, diverged=INTEGER)


def has_parquet() -> bool:
    """Whether ``pyarrow`` is importable, so that ``write_table`` also writes Parquet."""
    return importlib.util.find_spec("pyarrow") is not None


def table(rows: Sequence[Mapping], dtypes: Mapping[str, str], *, columns: Sequence[str] | None = None) -> pd.DataFrame:
    """A DataFrame of ``rows`` (dicts; ``None`` for a missing value), its columns in the order
    of ``columns`` (default: the first row's keys), each of the type ``dtypes`` names
    (``FLOAT`` for a column it does not name). Non-finite floats become NaN."""
    if columns is None:
        columns = list(rows[0]) if rows else list(dtypes)
    frame = pd.DataFrame.from_records(list(rows), columns=list(columns))
    types = {c: dtypes.get(c, FLOAT) for c in frame.columns}
    frame = frame.astype(types)
    floats = [c for c, t in types.items() if t == FLOAT]
    if floats:
        frame[floats] = frame[floats].where(np.isfinite(frame[floats]))
    return frame


def write_table(frame: pd.DataFrame, path: pathlib.Path | str) -> list[pathlib.Path]:
    """Write ``frame`` to ``path`` (``.csv``) and, when ``pyarrow`` is importable, to the same
    name with ``.parquet``; each atomically. Returns the paths written."""
    path = pathlib.Path(path)
    atomic_write_text(path, frame.to_csv(index=False, lineterminator="\n"))
    written = [path]
    if has_parquet():
        buf = io.BytesIO()
        frame.to_parquet(buf, index=False)
        atomic_write_bytes(path.with_suffix(".parquet"), buf.getvalue())
        written.append(path.with_suffix(".parquet"))
    return written


def read_table(path: pathlib.Path | str, dtypes: Mapping[str, str]) -> pd.DataFrame:
    """The DataFrame that ``write_table`` wrote as CSV to ``path``, with the column types of
    ``dtypes`` (``FLOAT`` for a column it does not name); empty cells are missing values
    and floats are parsed exactly."""
    path = pathlib.Path(path)
    header = pd.read_csv(path, nrows=0).columns
    types = {c: dtypes.get(c, FLOAT) for c in header}
    return pd.read_csv(path, dtype=types, keep_default_na=False, na_values=[""], **_EXACT)


# pandas 3 parses floats exactly by default (and deprecates the option); pandas 2 needs asking
_EXACT = {} if int(pd.__version__.split(".")[0]) >= 3 else {"float_precision": "round_trip"}


def infer_dtypes(rows: Sequence[Mapping]) -> dict[str, str]:
    """Column types from the values of ``rows``: booleans, integers (nullable where a value is
    ``None``), strings, else floats."""
    out = {}
    for c in rows[0] if rows else ():
        values = [r[c] for r in rows if r[c] is not None]
        if values and all(isinstance(v, bool | np.bool_) for v in values):
            out[c] = BOOLEAN if len(values) == len(rows) else "boolean"
        elif values and all(isinstance(v, int | np.integer) and not isinstance(v, bool) for v in values):
            out[c] = INTEGER if len(values) == len(rows) else NULLABLE_INTEGER
        elif values and all(isinstance(v, str) for v in values):
            out[c] = STRING
    return out


def write_csv(path: pathlib.Path | str, rows: Sequence[Mapping]) -> None:
    """Write ``rows`` (dicts with the same keys) with ``write_table``, column types from their
    values (``infer_dtypes``)."""
    write_table(table(rows, infer_dtypes(rows)), path)


# --- a sweep's tables ---------------------------------------------------------------------


def trial_columns(points: Point | Sequence[Point]) -> list[str]:
    """The columns of a sweep's ``trials.csv``, in order: every point column of ``points`` (a
    sweep's points, or one of them; points of other kinds have other settings)."""
    points = [points] if isinstance(points, Mapping) else points
    return (
        ["point_index", "seed", "trial_id"]
        + list(dict.fromkeys(c for p in points for c in p.columns))
        + ["base_seed", "method", "substeps"]
        + list(METRIC_COLUMNS)
        + ["diverged", "diverged_at"]
    )


def _with_texts(dtypes: Mapping[str, str], rows: Sequence[Mapping]) -> dict:
    """``dtypes`` plus ``STRING`` for every other column that holds text (a kind's gain given as
    a matrix, written as JSON)."""
    texts = {c for r in rows for c, v in r.items() if isinstance(v, str) and c not in dtypes}
    return dict(dtypes) | dict.fromkeys(texts, STRING)


def trials_frame(rows: Sequence[Mapping], columns: Sequence[str]) -> pd.DataFrame:
    """A sweep's trial rows (``sweep.collect``) as its tidy table: one row per trial."""
    return table(rows, _with_texts(TRIAL_DTYPES, rows), columns=columns)


def summary_rows(summary: Sequence[Mapping], numerics: Mapping) -> list[dict]:
    """A sweep's per-point entries (``sweep.summarize``) as flat rows: point columns, the
    ``numerics`` (method, substeps), counts, and ``<metric>_<stat>`` columns."""
    rows = []
    for entry in summary:
        row = entry["point"].columns | dict(numerics)
        row |= dict(trials=entry["trials"], n=entry["n"], diverged=entry["diverged"])
        for m, st in entry["stats"].items():
            row |= {f"{m}_{k}": st[k] for k in ("mean", "sd", "ci_lo", "ci_hi")}
        rows.append(row)
    return rows


def summary_frame(summary: Sequence[Mapping], numerics: Mapping) -> pd.DataFrame:
    """A sweep's per-point entries as its summary table: one row per point."""
    rows = summary_rows(summary, numerics)
    return table(rows, _with_texts(SUMMARY_DTYPES, rows), columns=list(dict.fromkeys(c for r in rows for c in r)))
