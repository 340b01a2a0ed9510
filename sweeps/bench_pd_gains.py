"""What PD's gains do for identification through 0.3 N m of joint friction (issue 35's PD case,
docs/experiment_design.md).

For each ``kp`` and ``kv`` of ``--gains`` (diagonal, the same on both axes) and each paper arm
location of ``--arms``: the trial of ``bench_design.py`` (PD, LuGre ``tau_c`` with ``tau_s =
1.5 tau_c``, force noise 0.05 N, 2^18-count encoders, the person's force 0.3 N RMS below 2 Hz),
a flat ShapedNoise in bursts (``--duty`` of each ``--burst`` period, ``--knots`` log-spaced
from ``--low`` to ``--high`` Hz) scaled to the paper's level-1 RMS, its 2.25 N peak and the
``--displacement`` limit on every arm's full simulation (``aj.signals.limited_signal``, key 0), and
``aj.predict_se`` of the arm's twelve entries over ``--draws`` noise draws of a ``--record``
second record. Reported per gain pair: each arm's drift under the person's force
(``aj.linear.drift``), the largest relative SE of the M, B, K diagonals per arm and which, and the
minutes for +-10% at 95% on all of them (one over the square root of the length). Through
stick-slip no Cramér-Rao bound holds, so ``predict_se`` (identify's own SEs, by Monte Carlo)
is the criterion, as in ``aj.design(method=aj.experiment.MonteCarlo())``. Saves strict JSON (``--out``)
with the settings and the package version.

    python sweeps/bench_pd_gains.py --gains 250:4,100:4,50:4,250:1,250:12,600:1 --out pd_gains.json
"""

from __future__ import annotations

import sys
import time

from armimp_jax.study.runs.cli import Parser, fail, script

PROG = "bench_pd_gains"


def parse(argv):
    p = Parser(prog="bench_pd_gains", description=__doc__.split("\n\n")[0])
    p.add_argument("--gains", default="250:4,100:4,50:4,250:1,250:12,600:1", help="kp:kv list [N/m]:[N s/m]")
    p.add_argument("--arms", default="1,2,3,4", help="paper arm locations (default 1,2,3,4)")
    p.add_argument("--tau-c", type=float, default=0.3, help="Coulomb torque [N m] (default 0.3)")
    p.add_argument("--duty", type=float, default=0.125, help="burst duty in (0, 1] (default 0.125)")
    p.add_argument("--burst", type=float, default=2.0, help="burst period [s] (default 2)")
    p.add_argument("--low", type=float, default=0.5, help="lowest knot [Hz] (default 0.5)")
    p.add_argument("--high", type=float, default=15.0, help="highest knot [Hz] (default 15)")
    p.add_argument("--knots", type=int, default=8, help="knots (default 8)")
    p.add_argument("--displacement", type=float, default=0.01, help="peak hand displacement limit [m]")
    p.add_argument("--record", type=float, default=20.0, help="record length [s] (default 20)")
    p.add_argument("--draws", type=int, default=16, help="predict_se's noise draws (default 16)")
    p.add_argument("--precision", type=float, default=0.1, help="relative half-width at 95%% (default 0.1)")
    p.add_argument("--out", default="pd_gains.json", help="JSON file of the results")
    a = p.parse_args(argv)
    try:
        a.gains = [tuple(float(v) for v in g.split(":")) for g in a.gains.split(",")]
        a.arms = [int(v) for v in a.arms.split(",")]
    except ValueError:
        fail(f"--gains must look like 250:4,100:4 and --arms like 1,2; got {a.gains!r}, {a.arms!r}", p.prog)
    if any(len(g) != 2 or min(g) <= 0 for g in a.gains) or not set(a.arms) <= {1, 2, 3, 4}:
        fail(f"--gains takes positive kp:kv pairs, --arms locations 1-4; got {a.gains}, {a.arms}", p.prog)
    if not (0 < a.duty <= 1 and a.burst > 0 and 0 < a.low < a.high and a.knots >= 2 and a.draws >= 8):
        fail("need 0 < --duty <= 1, --burst > 0, 0 < --low < --high, --knots >= 2 and --draws >= 8", p.prog)
    if a.record < 2 or a.displacement <= 0 or not 0 < a.precision < 1 or a.tau_c < 0:
        fail("need --record >= 2 s, --displacement > 0, 0 < --precision < 1 and --tau-c >= 0", p.prog)
    return a


@script(PROG)
def main(argv=None):
    a = parse(sys.argv[1:] if argv is None else argv)
    from armimp_jax.runtime import configure

    configure()
    import numpy as np

    from armimp_bench import design
    from armimp_jax.study.runs.results import atomic_write_json, stamped

    rows, t0 = [], time.perf_counter()
    for kp, kv in a.gains:
        row = design.one_pair(kp, kv, a)
        rows.append(row)
        per_arm = ", ".join(f"{w['relative_se']:.3f} ({w['entry']})" for w in row["worst"])
        print(
            f"kp {kp:g} N/m, kv {kv:g} N s/m: drift {np.round(row['drift_mm'], 2).tolist()} mm; largest relative SE "
            f"per arm {per_arm}; {row['minutes']:.1f} min for +-{a.precision:g} at 95% "
            f"({time.perf_counter() - t0:.0f} s)",
            flush=True,
        )
    settings = {k: v for k, v in vars(a).items() if k != "out"}
    atomic_write_json(a.out, dict(settings=stamped(settings), rows=rows, wall_s=time.perf_counter() - t0))
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
