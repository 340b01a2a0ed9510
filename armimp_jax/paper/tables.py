"""The reproduction's tidy tables: one row per condition, per claim, and per fitted matrix entry.

Drawn from the aggregate (``reproduce.aggregate``'s ``results``); ``result_tables`` gives all
three, ``reproduce.load_tables`` reads them from a run folder. Column types are declared
(``CONDITION_DTYPES``, ``FIT_DTYPES``, ``CLAIM_DTYPES``), so a CSV read back equals the frame.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from ..study.sweep.tables import INTEGER, STRING, table
from .claims import Condition

CONDITION_DTYPES = (
    dict(label=STRING, experiment=STRING, controller=STRING)
    | dict.fromkeys(("location", "friction", "perturbation", "n", "trials", "diverged"), INTEGER)
    | dict(acquisition=STRING)
)
FIT_DTYPES = CONDITION_DTYPES | dict(matrix=STRING, element=STRING, unit=STRING)
CLAIM_DTYPES = dict(key=STRING, verdict=STRING, robust="boolean", seeds=INTEGER)
CLAIM_DTYPES |= dict.fromkeys(("robustness", "ours", "claim", "rule", "left_out"), STRING)
_ELEMENTS = ("11", "12", "21", "22")  # (2, 2) matrices as rows or columns, [output, input], row-major
_FIT_UNITS = dict(M="kg", B="N s/m", K="N/m")


def _stats(prefix: str, mean, sd, half) -> dict:
    """``<prefix>_mean``, ``_sd``, ``_ci_lo``, ``_ci_hi`` of one number (``None``: undefined)."""
    nan = float("nan")
    mean, sd = (nan if v is None else v for v in (mean, sd))
    lo, hi = (nan, nan) if half is None else (mean - half, mean + half)
    return {f"{prefix}_mean": mean, f"{prefix}_sd": sd, f"{prefix}_ci_lo": lo, f"{prefix}_ci_hi": hi}


def _cells(value) -> list:
    """A (2, 2) list of a condition's means (``None`` where undefined) as four numbers."""
    return [None] * 4 if value is None else np.asarray(value, dtype=float).reshape(-1).tolist()


def _condition(entry: dict) -> dict:
    c = entry["condition"]
    return dict(label=Condition(**c).label, **c, n=entry["n"], trials=entry["trials"], diverged=entry["diverged"])


def conditions_frame(results: dict) -> pd.DataFrame:
    """One row per condition of ``results`` (``aggregate``'s): its fields and label, ``n``
    (trials that did not diverge), ``trials``, ``diverged``, and for every scalar metric
    (``phi_ij`` as ``phi_11`` .. ``phi_22``) ``<m>_mean``, ``<m>_sd`` and the 95% t-interval
    ``<m>_ci_lo``, ``<m>_ci_hi`` over the seeds (NaN where undefined). The fitted matrices
    are in ``fits_frame``."""
    rows = []
    for entry in results["conditions"]:
        row = _condition(entry)
        for m in (k for k in entry if k + "_sd" in entry and k + "_ci" in entry):
            if m == "phi_ij":
                cells = zip(_ELEMENTS, *(_cells(entry[m + s]) for s in ("", "_sd", "_ci")), strict=True)
                for e, mean, sd, half in cells:
                    row |= _stats(f"phi_{e}", mean, sd, half)
            elif not isinstance(entry[m], list):
                row |= _stats(m, entry[m], entry[m + "_sd"], entry[m + "_ci"])
        rows.append(row)
    return table(rows, CONDITION_DTYPES)


def fits_frame(results: dict) -> pd.DataFrame:
    """The fitted ``M``, ``B``, ``K`` of ``results`` (``aggregate``'s) in long form: one row
    per condition, matrix and element (``11``: [output x, input x]), with the arm's true
    value, the mean fit over the seeds with its standard deviation and 95% t-interval, the
    matrix's mean relative error ``||fit - true||_F / ||true||_F`` and the fit's mean overall
    VAF [%]. Results written before the fit existed give no rows."""
    rows = []
    for entry in results["conditions"]:
        if "truth" not in entry or "fit_M" not in entry:
            continue
        for sym, unit in _FIT_UNITS.items():
            key = f"fit_{sym}"
            cells = zip(_ELEMENTS, _cells(entry["truth"][sym]), *(_cells(entry[key + s]) for s in ("", "_sd", "_ci")))
            for e, true, mean, sd, half in cells:
                row = _condition(entry) | dict(matrix=sym, element=e, unit=unit, true=true)
                row |= {k.replace("fit_", "", 1): v for k, v in _stats("fit", mean, sd, half).items()}
                row |= dict(rel_error=entry[key + "_rel_error"], vaf=entry.get("fit_vaf"))
                rows.append(row)
    return table(rows, FIT_DTYPES, columns=None if rows else list(FIT_DTYPES))


def claims_frame(results: dict) -> pd.DataFrame:
    """The claims (a)-(f) of ``results`` (``aggregate``'s), one row each: ``verdict`` (from the
    condition means), ``robust`` (``<NA>`` under two seeds), ``seeds`` judged alone, the
    ``robustness`` and ``ours`` texts, the paper's ``claim``, the ``rule``, and the conditions
    ``left_out`` (every trial diverged; joined by "; "; ``<NA>``: none)."""
    rows = [
        {k: c[k] for k in ("key", "verdict", "robust", "seeds", "robustness", "ours", "claim", "rule")}
        | dict(left_out="; ".join(c["left_out"]) or None)
        for c in results["claims"]
    ]
    return table(rows, CLAIM_DTYPES, columns=list(CLAIM_DTYPES))


def result_tables(results: dict) -> dict[str, pd.DataFrame]:
    """``{"conditions": conditions_frame, "claims": claims_frame, "fits": fits_frame}`` of
    ``results``: the reproduction's tidy tables."""
    return dict(conditions=conditions_frame(results), claims=claims_frame(results), fits=fits_frame(results))
