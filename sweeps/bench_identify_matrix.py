"""The coverage matrix (armimp_bench.matrix): identify on every controller x friction law,
as a lab would run it, scored by issue 61's rule.

Per cell and seed a fresh recording is identified from a generic start with the friction known;
a run folder (--out) keeps one checked record per seed and cell (a rerun resumes; more seeds or
cells extend it). Printed per cell: converged and trusted fits, coverage of the 95% intervals
over the arm's diagonals, the SD of z per diagonal, z beyond 4, the fits failed or warned of
(with why), and the verdict against the bands (coverage 0.92-0.98, SD of z 0.8-1.25, at most one
z beyond 4).

    python sweeps/bench_identify_matrix.py --cells new-user,admittance/cv-0.05 --seeds 50 --out results/matrix
"""

from __future__ import annotations

import sys

from armimp_jax.study.runs.cli import Parser, fail, parse_names, script

PROG = "bench_identify_matrix"


def parse(argv):
    p = Parser(prog=PROG, description=__doc__.split("\n\n")[0])
    p.add_argument("--cells", default="new-user", help="comma list of cells (armimp_bench.matrix.CELLS), or all")
    p.add_argument("--seeds", type=int, default=50, help="recordings per cell (default 50)")
    p.add_argument("--draws", type=int, default=64, help="identify's noise draws (default 64)")
    p.add_argument("--out", default="results/matrix", help="run folder (resumed)")
    p.add_argument("--json", metavar="FILE", help="also write every cell's summary to FILE")
    a = p.parse_args(argv)
    if a.seeds < 2 or a.draws < 8:
        fail(f"need --seeds >= 2 and --draws >= 8; got {a.seeds} and {a.draws}", PROG)
    return a


@script(PROG)
def main(argv=None):
    a = parse(sys.argv[1:] if argv is None else argv)
    from armimp_jax.runtime import configure

    configure()
    from armimp_bench import matrix, protocol

    names = tuple(matrix.CELLS)  # checked before any fit
    cells = names if a.cells == "all" else parse_names(a.cells, names, PROG, option="--cells")
    done = protocol.study(
        cells, a.seeds, a.out, draws=a.draws, catalogue=matrix.cells(cells), catalogue_settings=matrix.settings()
    )
    summaries = {name: matrix.summary(c["seeds"]) for name, c in done.items()}
    print("\n".join(matrix.table_lines(summaries)))
    if a.json:
        from armimp_jax.study.runs.results import atomic_write_json

        atomic_write_json(a.json, {k: dict(s, verdict=matrix.verdict(s)) for k, s in summaries.items()})
    return 0


if __name__ == "__main__":
    sys.exit(main())
