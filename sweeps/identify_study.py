"""Bias and interval coverage of the classical FRF fit against identify, over friction, controller
and acquisition, with the person's own force on (docs/identification.md, section 7).

For each acquisition (instant samples, interval means), controller (PD, IMBIC) and
Coulomb torque (``--frictions``, tau_s = 1.5 tau_c): ``--seeds`` recordings of the paper's arm
at location 2 (force noise 0.05 N, 2^18-count encoders, voluntary force 0.3 N RMS below
2 Hz, perturbation peak 10 N, ``--seconds`` s), each estimated by ``aj.identify`` (the arm's
12 entries, the robot's friction known) and by the classical route of the same recording
(Welch + ``fit_impedance`` with the acquisition's model and spectral SEs). Per cell: the
share of 95% intervals holding the truth over the 12 entries, and the bias of the
estimates (the largest |mean error| over the spread of the estimates, over the entries).
A run folder (``--out``: one checked record per recording, resumed when rerun with the same
settings, and ``identify_study.json``); prints a Markdown table and draws ``--figure``
(``armimp_bench.classical``).

    python sweeps/identify_study.py --seeds 25 --out results/identify-study \
        --figure docs/figures/identification_study.png
"""

from __future__ import annotations

import sys

from armimp_jax.study.runs.cli import Parser, fail, script

PROG = "identify_study"


def parse(argv):
    p = Parser(prog="identify_study", description=__doc__.split("\n\n")[0])
    p.add_argument("--seeds", type=int, default=25, help="recordings per cell (default 25)")
    p.add_argument("--seconds", type=float, default=10.0, help="record length [s] (default 10)")
    p.add_argument("--frictions", default="0,0.2,1,4", help="Coulomb torques [N m] (default 0,0.2,1,4)")
    p.add_argument("--draws", type=int, default=64, help="identify's noise draws (default 64)")
    p.add_argument("--out", default="results/identify-study", help="run folder of the results (resumed)")
    p.add_argument("--figure", default=None, help="PNG of the bias and coverage against friction")
    a = p.parse_args(argv)
    try:
        a.frictions = [float(t) for t in a.frictions.split(",")]
    except ValueError:
        fail(f"--frictions must be numbers like 0,0.2,1; got {a.frictions!r}", p.prog)
    if a.seeds < 3 or a.seconds < 2 or a.draws < 8 or any(t < 0 for t in a.frictions):
        fail("need --seeds >= 3, --seconds >= 2, --draws >= 8 and frictions >= 0", p.prog)
    return a


@script(PROG)
def main(argv=None):
    a = parse(sys.argv[1:] if argv is None else argv)
    from armimp_jax.runtime import configure

    configure()
    from armimp_bench import classical

    state = classical.run(a, a.out)
    print()
    print(classical.table(state, a))
    if a.figure:
        print(f"figure: {classical.figure(state, a, a.figure)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
