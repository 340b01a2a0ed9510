"""Check a design on the Cramér-Rao bound by Monte Carlo identification (issue 35).

    python sweeps/bench_design_bound.py DESIGN_DIR --seeds 30 --out DIR [--arms 1,2] [--markdown]

DESIGN_DIR is what design_experiment.py wrote (design.json with its config and the designed
controller, perturbation.csv). Per arm of the design's robust set: SEEDS recordings of the
designed experiment under new noise (keys 70000 + seed) at the design's record length, each
identified from the truth (the arm's 12 entries, statistic "auto", 32 draws). It reports per
diagonal entry the bound, the spread, spread / bound and the coverage of the 95% intervals,
and the largest achieved relative spread over the targets against the bound's: the minutes
the design promises follow from the bound by its one-over-square-root law, so this ratio,
squared, is how far the Monte Carlo minutes are from the promised ones. A run folder
(``--out``: one checked record per recording, saved as it finishes, so a rerun resumes; and
``design_bound.json``); --arms and --first split the work over processes (one --out each),
and --merge DIR_A DIR_B ... --out DIR combines them (``armimp_bench.design``).
"""

from __future__ import annotations

import pathlib
import sys

from armimp_jax.study.runs.cli import Parser, script

PROG = "bench_design_bound"


def parse(argv):
    p = Parser(prog=PROG, description=__doc__)
    p.add_argument("design", type=pathlib.Path, help="the folder design_experiment.py wrote")
    p.add_argument("--seeds", type=int, default=30, help="recordings per arm (default 30)")
    p.add_argument("--first", type=int, default=0, help="the first seed (default 0): processes share an arm's seeds")
    p.add_argument(
        "--merge", nargs="+", type=pathlib.Path, metavar="DIR", help="combine these run folders into --out (no runs)"
    )
    p.add_argument("--arms", default=None, help="comma-separated indices into the design's arms, from 1 (default all)")
    p.add_argument("--out", type=pathlib.Path, required=True, help="run folder of the results (resumed)")
    p.add_argument("--markdown", action="store_true", help="print the saved results as a Markdown table (no runs)")
    a = p.parse_args(argv)
    if a.first < 0:
        p.error(f"--first must be >= 0, got {a.first}")
    if a.seeds < 2 and a.merge is None:
        p.error(f"--seeds must be >= 2 (a spread), got {a.seeds}")
    return a


@script(PROG)
def main(argv=None):
    a = parse(sys.argv[1:] if argv is None else argv)
    from armimp_jax.runtime import configure

    configure()
    from armimp_bench import design
    from armimp_jax.study.runs.results import read_json

    if a.markdown:
        design.print_markdown(read_json(a.out / "design_bound.json"))
        return 0
    if a.merge:
        doc, trials, _ = design.designed_trials(a.design)
        states = [read_json(m / "design_bound.json") for m in a.merge]
        design.merge(a, doc, trials, states)
        return 0
    design.print_markdown(design.check_bound_design(a, a.out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
