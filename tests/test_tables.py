"""armimp_jax.study.sweep.tables: tables written by pandas read back exactly, in the CSV format the
sweep's files have always had (empty cells for undefined numbers, floats as Python's repr)."""

import csv
import io
import math

import numpy as np
import pandas as pd

from armimp_jax.study.sweep import tables

DTYPES = dict(name=tables.STRING, level=tables.NULLABLE_INTEGER, count=tables.INTEGER, ok=tables.BOOLEAN)


def rows(n=400, seed=0):
    rng = np.random.default_rng(seed)
    x = rng.standard_normal(n) * 10.0 ** rng.integers(-300, 300, n)
    x[:6] = [0.1, 1 / 3, 1e-5, 1e16, -0.0, 5e-324]
    out = []
    for i, v in enumerate(x):
        out.append(
            dict(
                name=("a,b" if i % 7 == 0 else f"p{i}") if i % 5 else None,
                level=None if i % 3 == 0 else i,
                count=i,
                ok=bool(i % 2),
                value=float(v),
                gap=[None, math.nan, math.inf, -math.inf, 2.5][i % 5],
            )
        )
    return out


def reference_csv(rs) -> str:
    """The csv-module writer the sweep used before pandas: empty cells for None and
    non-finite floats, floats as repr."""
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(rs[0]), lineterminator="\n")
    w.writeheader()
    for r in rs:
        w.writerow(
            {
                k: ("" if v is None or (isinstance(v, float) and not math.isfinite(v)) else repr(v))
                if v is None or isinstance(v, float)
                else v
                for k, v in r.items()
            }
        )
    return buf.getvalue()


def test_csv_is_the_old_format_and_reads_back_exactly(tmp_path):
    rs = rows()
    frame = tables.table(rs, DTYPES)
    assert dict(frame.dtypes.astype(str)) == dict(
        name="string", level="Int64", count="int64", ok="bool", value="float64", gap="float64"
    )
    path = tmp_path / "t.csv"
    tables.write_table(frame, path)
    assert path.read_text() == reference_csv(rs)
    back = tables.read_table(path, DTYPES)
    pd.testing.assert_frame_equal(back, frame, check_exact=True)
    # every float bit for bit, the sign of -0.0 and the smallest subnormal included
    assert back["value"].to_numpy().tobytes() == np.array([r["value"] for r in rs]).tobytes()
    assert back["gap"].isna().sum() == 4 * len(rs) // 5  # None, NaN and both infinities: undefined


def test_column_types_are_inferred_for_plain_rows(tmp_path):
    rs = rows(20)
    assert tables.infer_dtypes(rs) == dict(
        name="string", level="Int64", count="int64", ok="bool"
    )  # value and gap: floats
    tables.write_csv(tmp_path / "t.csv", rs)
    assert (tmp_path / "t.csv").read_text() == reference_csv(rs)


def test_parquet_is_written_next_to_the_csv_with_the_same_table(tmp_path):
    frame = tables.table(rows(50), DTYPES)
    written = tables.write_table(frame, tmp_path / "t.csv")
    assert written == [tmp_path / "t.csv", tmp_path / "t.parquet"]
    pd.testing.assert_frame_equal(pd.read_parquet(tmp_path / "t.parquet").astype(frame.dtypes), frame, check_exact=True)
