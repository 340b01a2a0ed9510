"""What PD's gains do for identification through 0.3 N m of joint friction (issue 35's PD case,
docs/experiment_design.md).

For each ``kp`` and ``kv`` of ``--gains`` (diagonal, the same on both axes) and each paper arm
location of ``--arms``: the trial of ``bench_design.py`` (PD, LuGre ``tau_c`` with ``tau_s =
1.5 tau_c``, force noise 0.05 N, 2^18-count encoders, the person's force 0.3 N RMS below 2 Hz),
a flat ShapedNoise in bursts (``--duty`` of each ``--burst`` period, ``--knots`` log-spaced
from ``--low`` to ``--high`` Hz) scaled to the paper's level-1 RMS, its 2.25 N peak and the
``--displacement`` limit on every arm's full simulation (``aj.limited_signal``, key 0), and
``aj.predict_se`` of the arm's twelve entries over ``--draws`` noise draws of a ``--record``
second record. Reported per gain pair: each arm's drift under the person's force
(``aj.drift``), the largest relative SE of the M, B, K diagonals per arm and which, and the
minutes for +-10% at 95% on all of them (one over the square root of the length). Through
stick-slip no Cramér-Rao bound holds, so ``predict_se`` (identify's own SEs, by Monte Carlo)
is the criterion, as in ``aj.design(method="monte_carlo")``. Saves strict JSON (``--out``)
with the settings and the package version.

    python sweeps/bench_pd_gains.py --gains 250:4,100:4,50:4,250:1,250:12,600:1 --out pd_gains.json
"""

from __future__ import annotations

import sys
import time

from _cli import Z95, Parser, bench_noise, fail

TARGETS = [f"arm.{n}[{i},{i}]" for n in ("mass", "damping", "stiffness") for i in (0, 1)]
FREE = ("arm.mass", "arm.damping", "arm.stiffness")


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


def one_pair(aj, np, jax, kp: float, kv: float, a) -> dict:
    """The drift, the limited signal's RMS and peak, and per arm the largest relative SE."""
    from armimp_jax import paper
    from armimp_jax.study import design_experiment as dx

    control = aj.PD(kp=kp * np.eye(2), kv=kv * np.eye(2))
    trials = [
        aj.make_trial(control, arm=paper.arm(loc), friction=aj.LuGre(a.tau_c, 1.5 * a.tau_c), **bench_noise(aj))
        for loc in a.arms
    ]
    n = int(round(a.record * 1000))
    level1 = np.asarray(aj.PaperNoise(paper.perturbation_peak(1)).signal(jax.random.key(2024), n))
    limits = aj.Limits(
        rms_force=tuple(np.sqrt(np.mean(level1**2, axis=0))),
        peak_force=2.25,
        record=a.record,
        peak_displacement=a.displacement,
    )
    knots = np.geomspace(a.low, a.high, a.knots)
    family = aj.ShapedNoise(knots, np.ones((2, a.knots)), 1.0, duty=a.duty, burst=a.burst)
    signal = np.asarray(aj.limited_signal(family, limits, key=jax.random.key(0), trials=trials))
    worst = []
    for t in trials:
        rel = dx.relative_se(aj.predict_se(t, signal, free=FREE, draws=a.draws), t, free=FREE, targets=TARGETS)
        label = max(rel, key=rel.get)
        worst.append(dict(relative_se=float(rel[label]), entry=label))
    largest = max(w["relative_se"] for w in worst)
    return dict(
        kp=kp,
        kv=kv,
        drift_mm=[1e3 * float(aj.drift(t)) for t in trials],
        rms_force=np.sqrt(np.mean(signal**2, axis=0)).tolist(),
        peak_force=np.abs(signal).max(axis=0).tolist(),
        worst=worst,
        minutes=a.record / 60.0 * (largest / (a.precision / Z95)) ** 2,
    )


def main(argv=None):
    a = parse(sys.argv[1:] if argv is None else argv)
    import jax

    jax.config.update("jax_enable_x64", True)
    import numpy as np

    import armimp_jax as aj
    from armimp_jax.study import atomic_write_json, stamped

    rows, t0 = [], time.perf_counter()
    for kp, kv in a.gains:
        row = one_pair(aj, np, jax, kp, kv, a)
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
