"""Benchmark: ``aj.record_for`` on two realistic cases, first call and warm calls apart.

    python sweeps/bench_record_for.py [--cases paper design] [--repeats 3] [--draws 64] [--parts]
        [--out results/bench/record_for.json]

``paper``: IMBIC through LuGre 1.0 / 1.5 N m at the paper's arm location 2, its level-1
perturbation, 20 s, the arm's matrices free; ``design``: design_imbic.toml's trial at arm
location 2 under its starting multisine within its limits, 20 s. Each case times ``record_for``
as it answers by default and with ``check=True`` (a second ``predict_se`` at the answer's
length); ``--parts`` also times ``crlb`` and each ``predict_se`` alone. The first call
(compilation included) is reported apart from the median of ``--repeats`` warm calls, wall and
CPU seconds (armimp_jax.bench.record).
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
    ap.add_argument("--parts", action="store_true", help="also time crlb and each predict_se alone, warm")
    ap.add_argument("--out", type=pathlib.Path, default=None)
    return ap


if __name__ == "__main__":
    ARGS = parser().parse_args()
    from armimp_jax.bench import record

    sys.exit(record.main(ARGS))
