"""Intervals entry by entry (issue 50; armimp_bench.entrywise): a one-factor-at-a-time
design around IMBIC through 0.5 N m with a strong person's force, 10 s records.

Per cell and seed a fresh recording is identified, started at the truth; reported per cell:
the coverage of the 95% intervals over the arm's entries and the SD of z entry by entry. A run
folder (--out) keeps one checked record per seed and cell (a rerun resumes; more seeds extend
it) and protocol.json. Cells: base, record-5, record-20, force-0.1, force-0.3, friction-0,
friction-1, arm-1, arm-3, arm-4, pd (the module's docstring says what each changes).

    python sweeps/bench_identify_entries.py --cells base,record-5 --seeds 50 --out results/entries

--oracle adds, per cell, what an exactly honest linear estimator's SD of z would be on the same
recordings (``entrywise.oracle``: the recordings' own sampling luck, a band to read the cell's
SD of z against).
"""

from __future__ import annotations

import sys

from armimp_jax.study.runs.cli import Parser, fail, parse_names, script

PROG = "bench_identify_entries"
CELLS = ("base", "record-5", "record-20", "force-0.1", "force-0.3", "friction-0", "friction-1")
MORE = ("arm-1", "arm-3", "arm-4", "pd", "friction-1-arm-4")
SYMBOL = {"arm.mass": "M", "arm.damping": "B", "arm.stiffness": "K"}


def parse(argv):
    p = Parser(prog=PROG, description=__doc__.split("\n\n")[0])
    names = ", ".join(CELLS + MORE)
    p.add_argument("--cells", default="base", help=f"comma list of {names} (default base)")
    p.add_argument("--seeds", type=int, default=50, help="recordings per cell (default 50)")
    p.add_argument("--draws", type=int, default=64, help="identify's noise draws (default 64)")
    p.add_argument("--out", default="results/entries", help="run folder (resumed)")
    p.add_argument("--oracle", action="store_true", help="also the oracle's SD of z per cell (entrywise.oracle)")
    a = p.parse_args(argv)
    a.cells = parse_names(a.cells, CELLS + MORE, PROG, option="--cells")
    if a.seeds < 2 or a.draws < 8:
        fail(f"need --seeds >= 2 and --draws >= 8; got {a.seeds} and {a.draws}", PROG)
    return a


def _table(cells: dict) -> str:
    lines = ["| cell | converged | coverage (diagonals) | SD of z per diagonal |", "|---|---|---|---|"]
    for name, c in cells.items():
        s = c["summary"]
        sds, hits = [], []
        for n, entry in s.get("parameters", {}).items():
            if n.startswith("arm."):
                for (i, j), k in (((0, 0), 0), ((1, 1), 3)):
                    sds.append(f"{SYMBOL[n]}{i}{j} {entry['sd_z'][k]:.2f}")
                    hits.append(entry["coverage"][k])
        cover = f"{sum(hits) / len(hits):.3f}" if hits else "-"
        lines.append(f"| {name} | {s['converged']}/{s['recordings']} | {cover} | {', '.join(sds)} |")
    return "\n".join(lines)


@script(PROG)
def main(argv=None):
    a = parse(sys.argv[1:] if argv is None else argv)
    from armimp_jax.runtime import configure

    configure()
    from armimp_bench import entrywise, protocol

    catalogue = entrywise.cells(a.cells)
    cells = protocol.study(
        a.cells, a.seeds, a.out, draws=a.draws, catalogue=catalogue, catalogue_settings=entrywise.settings()
    )
    print(_table(cells))
    for name in a.cells if a.oracle else ():
        o = entrywise.oracle(name, a.seeds, draws=a.draws)
        sd, share = (dict(zip(o["labels"], o[k], strict=True)) for k in ("sd_z", "prior_share"))
        diag = [(f"{SYMBOL[n]}{i}{i}", f"{n}[{i},{i}]") for n in SYMBOL for i in (0, 1)]
        print(f"oracle {name} ({a.seeds} recordings): SD of z {', '.join(f'{s} {sd[k]:.2f}' for s, k in diag)}")
        nuisance = [f"{k} {v['sd_z']:.2f} ({v['prior_share']:.0%})" for k, v in o["nuisance"].items()]
        print(f"  the prior's share of identify's variance: {', '.join(f'{s} {share[k]:.0%}' for s, k in diag)}")
        print(f"  nuisances, SD of z (the prior's share): {', '.join(nuisance) or 'none'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
