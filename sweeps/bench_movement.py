"""Coverage of the classical route during a movement (``aj.estimate_ensemble``) over Monte Carlo
ensembles of the base case (``armimp_bench.movement``: paper arm 3, a 12 cm reach in 0.8 s,
K dipping to 40% at mid-reach through five knots, PD without friction, the still studies' noise).

Each ensemble: ``--repetitions`` reaches, each with its own perturbation and noise, fitted for every ``--windows``;
one record per ensemble in ``--out`` (resumed), and ``movement_coverage.json``: each knot's K, B diagonal coverage.

    python sweeps/bench_movement.py --ensembles 50 --repetitions 50 --out results/movement-coverage
    python sweeps/bench_movement.py --route model --case imbic --repetitions 40 --out results/movement-model-imbic
"""

import json
import sys

from armimp_bench.movement_options import coverage, setup
from armimp_jax.study.runs.cli import script


@script("bench_movement")
def main(argv=None):
    a = setup(argv, __doc__.split("\n\n")[0])  # the options, then JAX: --help answers at once
    print(json.dumps(coverage(a), indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
