"""Benchmark-only baseline: the same model as a plain scalar loop, compiled with numba.

What a careful person would write by hand: one trajectory per call, RK4 with
``sin/cos`` evaluated at every stage (``cos/sin(q1 - q2)`` by angle identities), PD or
IMBIC (velocity acceleration estimate), instant acquisition. ``simulate_many`` runs one
trajectory per thread (``prange``). Used by ``bench_simulate.py``, which also checks that
it agrees with the JAX simulator; run on its own, it does that check for a small batch:

    python sweeps/numba_baseline.py [--batch 4] [--seconds 0.5] [--substeps 10] [--controller imbic]
"""

from __future__ import annotations

import argparse
import sys

NEEDS_NUMBA = "needs numba (pip install -e '.[bench]')"


def parser() -> argparse.ArgumentParser:
    """The command line (built before numba and JAX are imported: ``--help`` needs neither)."""
    ap = argparse.ArgumentParser(
        prog="numba_baseline", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--batch", type=int, default=4, help="trials (default 4)")
    ap.add_argument("--seconds", type=float, default=0.5, help="record length [s] (default 0.5)")
    ap.add_argument("--substeps", type=int, default=10, help="RK4 substeps per 1 ms (default 10)")
    ap.add_argument("--controller", choices=("imbic", "pd"), default="imbic")
    ap.add_argument("--repeats", type=int, default=3, help="timed runs, median reported (default 3)")
    return ap


if __name__ == "__main__":
    ARGS = parser().parse_args()
    try:
        import numba  # noqa: F401
    except ImportError:
        sys.stderr.write(f"numba_baseline: error: {NEEDS_NUMBA}\n")
        sys.exit(2)
    from armimp_bench import numba_baseline

    numba_baseline.main(ARGS)
