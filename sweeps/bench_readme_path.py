"""Benchmark: the README's path against plain XLA, and the numba reference.

Three child processes, alternating, each timing 24 IMBIC trials (5 s, the four arms and
seven friction levels cycled, RK4 at 100 substeps: the issue's workload) through
``aj.simulate_batch``: ``readme`` (``aj.runtime.configure()``, what the README shows),
``plain`` (float64 switched on, nothing configured: plain XLA, since importing the package
sets nothing) and, with numba installed, ``numba`` (``sweeps/numba_baseline.py`` on one
thread). Compile excluded (the first call), ``block_until_ready``, median of ``--repeats``
calls per process, ratios from one run.

    python sweeps/bench_readme_path.py [--repeats 5] [--rounds 2]
"""

from __future__ import annotations

import sys

from armimp_jax.study.runs.cli import Parser


def main(argv=None):
    p = Parser(prog="bench_readme_path", description=__doc__.split("\n\n")[0])
    p.add_argument("--repeats", type=int, default=5, help="timed calls per process (default 5)")
    p.add_argument("--rounds", type=int, default=2, help="alternating rounds of the processes (default 2)")
    p.add_argument("--child", default=None, help="internal: run one process of the comparison")
    a = p.parse_args(sys.argv[1:] if argv is None else argv)
    from armimp_bench import readme_path

    if a.child:
        readme_path.child(a.child, a.repeats)
    else:
        readme_path.compare(a, script=__file__)


if __name__ == "__main__":
    main()
