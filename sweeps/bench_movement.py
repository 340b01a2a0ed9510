"""Coverage of the classical route during a movement (``aj.estimate_ensemble``) over Monte Carlo
ensembles of the base case (``armimp_jax.bench.movement``: paper arm 3, a 12 cm reach in 0.8 s,
K dipping to 40% at mid-reach through five knots, PD without friction, the still studies' noise).

Each ensemble is ``--repetitions`` reaches, each with its own perturbation and noise, fitted for
every ``--windows``; one record per ensemble in ``--out`` (a rerun resumes), and
``movement_coverage.json``: per fit, each knot's K and B diagonal coverage of its 95% intervals.

    python sweeps/bench_movement.py --ensembles 50 --repetitions 50 --out results/movement-coverage
"""

import json
import sys

from armimp_jax.study.cli import Parser, fail, script


@script("bench_movement")
def main(argv=None):
    p = Parser(prog="bench_movement", description=__doc__.split("\n\n")[0])
    p.add_argument("--ensembles", type=int, default=50, help="ensembles (default 50)")
    p.add_argument("--repetitions", type=int, default=50, help="reaches per ensemble (default 50)")
    p.add_argument("--peak", type=float, default=2.25, help="perturbation peak [N] per axis (default 2.25)")
    p.add_argument("--windows", default="0.1", help="windows [s] beyond the end knots, comma list (default 0.1)")
    p.add_argument("--out", default="results/movement-coverage", help="run folder (resumed)")
    a = p.parse_args(sys.argv[1:] if argv is None else argv)
    a.windows = [float(w) for w in a.windows.split(",")]
    if a.ensembles < 2 or a.repetitions < 23:
        fail("need --ensembles >= 2, --repetitions >= 23 (five knots)", p.prog)
    from armimp_jax.runtime import configure

    configure()
    from armimp_jax.bench import movement

    print(json.dumps(movement.classical_coverage(a, a.out)["summary"], indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
