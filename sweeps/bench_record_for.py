"""Benchmark: ``aj.record_for`` on two realistic cases, first call and warm calls apart.

    python sweeps/bench_record_for.py [--cases paper design] [--repeats 3] [--draws 64] [--check] [--parts]
        [--check-record 120] [--out results/bench/record_for.json]

``paper``: IMBIC through LuGre 1.0 / 1.5 N m at the paper's arm location 2, its level-1
perturbation, 20 s, the arm's matrices free; ``design``: design_imbic.toml's trial at arm
location 2 under its starting multisine within its limits, 20 s. Each case times ``record_for``
as it answers by default; ``--check`` also with ``check=True`` (a second ``predict_se`` at the
answer's length); ``--parts`` times ``crlb`` and ``predict_se`` alone, and ``predict_se`` at
``--check-record`` seconds (the check of an answer that long). The first call
(compilation included) is reported apart from the median of ``--repeats`` warm calls, wall and
CPU seconds (armimp_bench.record).
"""

from __future__ import annotations

import argparse
import pathlib
import sys


def parser() -> argparse.ArgumentParser:
    """The command line (no JAX: ``--help`` is instant)."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cases", nargs="+", choices=("paper", "design"), default=["paper", "design"])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--draws", type=int, default=64)
    ap.add_argument("--check", action="store_true", help="also time record_for(check=True)")
    ap.add_argument("--parts", action="store_true", help="also time crlb and predict_se alone")
    ap.add_argument("--check-record", type=float, default=120.0, help="--parts: predict_se at this record [s] too")
    ap.add_argument("--out", type=pathlib.Path, default=None)
    return ap


if __name__ == "__main__":
    ARGS = parser().parse_args()
    from armimp_bench import record

    sys.exit(record.main(ARGS))
