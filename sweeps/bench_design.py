"""Experiment design against the paper's perturbation (issue 28's benchmark, docs/experiment_design.md).

For each case (PD or IMBIC, Coulomb torque tau_c with tau_s = 1.5 tau_c; force noise 0.05 N,
2^18-count encoders, voluntary force 0.3 N RMS below 2 Hz), robust over the paper's four
arm locations: the limits are the RMS of the paper's level-1 perturbation (its 2.25 N peak,
key 2024, per axis) and that same peak, ``--record`` seconds, a hand displacement limit;
``aj.design`` shapes a ShapedNoise (log-spaced knots from ``--low`` to 15 Hz, flat start, in
bursts of each ``--duty``: the design starts from the best) to minimise the largest relative
SE among the diagonals of M, B and K over the four arms. Reported: that criterion for the
paper's perturbation, the flat continuous noise, each start and the design (``predict_se``, the same draws),
the limits the design meets, its time, and a Monte Carlo check: ``--seeds`` recordings per
arm with the designed perturbation, each identified from the truth; the estimates' spread
over the predicted SE per target, and the largest relative spread against the predicted
criterion. Saves strict JSON (``--out``) with the settings and the package version.

    python sweeps/bench_design.py --seeds 40 --out bench_design.json
"""

from __future__ import annotations

import sys
import time

from _cli import Parser, bench_noise, fail, parse_cases

TARGETS = [f"arm.{n}[{i},{i}]" for n in ("mass", "damping", "stiffness") for i in (0, 1)]
FREE = ("arm.mass", "arm.damping", "arm.stiffness")


def parse(argv):
    p = Parser(prog="bench_design", description=__doc__.split("\n\n")[0])
    p.add_argument("--cases", default="pd:0.3,imbic:1", help="controller:tau_c list [N m] (default pd:0.3,imbic:1)")
    p.add_argument("--record", type=float, default=20.0, help="record length [s] (default 20)")
    p.add_argument("--steps", type=int, default=30, help="design steps (default 30)")
    p.add_argument("--draws", type=int, default=16, help="noise draws per arm per step (default 16)")
    p.add_argument("--displacement", type=float, default=0.01, help="peak hand displacement limit [m] (default 0.01)")
    p.add_argument("--low", type=float, default=0.5, help="lowest knot of the ShapedNoise [Hz] (default 0.5)")
    p.add_argument("--knots", type=int, default=8, help="knots from --low to 15 Hz, log-spaced (default 8)")
    p.add_argument("--duty", default="1,0.25,0.125", help="burst duties of the candidate starts (default 1,0.25,0.125)")
    p.add_argument("--burst", type=float, default=2.0, help="burst period [s] (default 2)")
    p.add_argument("--learning-rate", type=float, default=0.15, help="Adam's learning rate (default 0.15)")
    p.add_argument("--seeds", type=int, default=40, help="Monte Carlo recordings per arm (default 40; 0: none)")
    p.add_argument("--out", default="bench_design.json", help="JSON file of the results")
    a = p.parse_args(argv)
    a.cases = parse_cases(a.cases, p.prog, "pd:0.3,imbic:1")
    if any(c not in ("pd", "imbic") or t < 0 for c, t in a.cases):
        fail(f"--cases: controller pd or imbic and tau_c >= 0; got {a.cases}", p.prog)
    if a.record < 2 or a.steps < 1 or a.draws < 8 or a.seeds < 0 or a.displacement <= 0:
        fail("need --record >= 2, --steps >= 1, --draws >= 8, --seeds >= 0 and --displacement > 0", p.prog)
    try:
        a.duty = [float(d) for d in a.duty.split(",")]
    except ValueError:
        fail(f"--duty must be a comma-separated list of numbers in (0, 1]; got {a.duty!r}", p.prog)
    if not all(0 < d <= 1 for d in a.duty) or a.burst <= 0:
        fail(f"--duty values must lie in (0, 1] and --burst > 0 s; got {a.duty}, {a.burst}", p.prog)
    if not (0 < a.low < 15 and a.knots >= 2 and a.learning_rate > 0):
        fail("need 0 < --low < 15 Hz, --knots >= 2 and --learning-rate > 0", p.prog)
    return a


def criterion(dx, preds, trials):
    """The largest relative SE over the targets and the trials, and per trial per target."""
    per = [dx.relative_se(pred, t, free=FREE, targets=TARGETS) for pred, t in zip(preds, trials)]
    return max(max(r.values()) for r in per), per


def make_case(aj, np, jax, controller, tau_c, a):
    """``(trials, paper_signal, limits, knots)`` of one case: the four arms, the paper's level-1
    perturbation (key 2024), the limits at its RMS and peak, and the ShapedNoise knots [Hz]."""
    from armimp_jax import paper

    trials = [
        aj.make_trial(
            aj.PD() if controller == "pd" else aj.IMBIC(),
            arm=paper.arm(loc),
            friction=aj.LuGre(tau_c, 1.5 * tau_c),
            **bench_noise(aj),
        )
        for loc in (1, 2, 3, 4)
    ]
    n = int(round(a.record * 1000))
    paper_signal = np.asarray(aj.PaperNoise(paper.perturbation_peak(1)).signal(jax.random.key(2024), n))
    rms = np.sqrt(np.mean(paper_signal**2, axis=0))
    limits = aj.Limits(rms_force=tuple(rms), peak_force=2.25, record=a.record, peak_displacement=a.displacement)
    return trials, paper_signal, limits, np.geomspace(a.low, 15.0, a.knots)


def run_design(aj, np, trials, limits, knots, a, name):
    """``aj.design`` from one flat ShapedNoise start per ``--duty``, printing each step."""
    starts = [aj.ShapedNoise(knots, np.ones((2, a.knots)), 1.0, duty=d, burst=a.burst) for d in a.duty]
    t0 = time.perf_counter()

    def progress(step, steps, value):
        print(f"  {name}: step {step}/{steps}, criterion {value:.4g} ({time.perf_counter() - t0:.0f} s)")

    return aj.design(
        trials[0],
        starts,
        free=FREE,
        limits=limits,
        targets=TARGETS,
        robust_over=trials,
        steps=a.steps,
        draws=a.draws,
        learning_rate=a.learning_rate,
        progress=progress,
    )


def compare(aj, np, jax, dx, result, trials, paper_signal, limits, knots, a) -> dict:
    """``{signal: (criterion, per trial per target)}`` predicted for the paper's perturbation,
    the flat continuous noise, the design's start and the design, all on the same draws (key 0)."""
    flat = aj.ShapedNoise(knots, np.ones((2, a.knots)), 1.0)
    flat_signal = aj.limited_signal(flat, limits, key=jax.random.split(jax.random.key(0))[0], trials=trials)
    signals = dict(paper=paper_signal, flat=flat_signal, start=result.start_signal, designed=result.signal)
    return {
        k: criterion(dx, [aj.predict_se(t, s, free=FREE, draws=64) for t in trials], trials) for k, s in signals.items()
    }


def monte_carlo(dc, result, trials, predicted, a) -> dict:
    """``--seeds`` recordings per arm with the designed signal, each identified from the truth:
    the relative spread per target against the predicted relative SE."""
    crit_after, per_after = predicted
    labels = list(result.before[0].labels)
    check = dc.validate(result.signal, trials, FREE, seeds=a.seeds)
    spread_rel, ratios = [], []
    for k, (t, v) in enumerate(zip(trials, check)):
        truth = dc.truth(t, FREE)
        row = {}
        for lab in TARGETS:
            row[lab] = float(v["spread"][labels.index(lab)] / abs(truth[labels.index(lab)]))
            ratios.append(row[lab] / per_after[k][lab])
        spread_rel.append(row)
    achieved_crit = max(max(r.values()) for r in spread_rel)
    print(
        f"  Monte Carlo ({a.seeds} per arm): largest relative spread {achieved_crit:.4g} against predicted "
        f"{crit_after:.4g} ({achieved_crit / crit_after:.2f}); spread / predicted SE per target and arm "
        f"{min(ratios):.2f}-{max(ratios):.2f}",
        flush=True,
    )
    return dict(
        seeds=a.seeds,
        recordings=[v["recordings"] for v in check],
        diverged=[v["diverged"] for v in check],
        converged=[v["converged"] for v in check],
        relative_spread=spread_rel,
        spread_over_predicted=ratios,
        criterion_achieved=achieved_crit,
        achieved_over_predicted=achieved_crit / crit_after,
    )


def run_case(aj, np, jax, controller, tau_c, a):
    """One case: the design, its comparison with the other signals and (``--seeds``) its check."""
    from armimp_jax.study import design_check as dc
    from armimp_jax.study import design_experiment as dx

    trials, paper_signal, limits, knots = make_case(aj, np, jax, controller, tau_c, a)
    result = run_design(aj, np, trials, limits, knots, a, f"{controller} {tau_c:g}")
    crit = compare(aj, np, jax, dx, result, trials, paper_signal, limits, knots, a)
    out = dict(
        controller=controller,
        tau_c=tau_c,
        paper_rms_force=np.asarray(limits.rms_force).tolist(),
        criterion={k: c for k, (c, _) in crit.items()},
        start_duty=result.start_family.duty,
        start_criteria=dict(zip([str(d) for d in a.duty], result.start_criteria)),
        paper_over_designed=crit["paper"][0] / crit["designed"][0],
        relative_se={k: per for k, (_, per) in crit.items()},
        achieved=result.achieved,
        design_time_s=result.time_s,
        improved=result.improved,
        skipped_steps=result.skipped,
        trace=result.trace,
        shape=np.asarray(result.family.shape).tolist(),
        knots=np.asarray(result.family.knots).tolist(),
    )
    print(
        f"{controller} {tau_c:g} N m: largest relative SE, paper {crit['paper'][0]:.4g}, flat continuous "
        f"{crit['flat'][0]:.4g}, start (duty {result.start_family.duty:g}; candidates {result.start_criteria}) "
        f"{crit['start'][0]:.4g}, designed {crit['designed'][0]:.4g} ({out['paper_over_designed']:.2f}x; improved "
        f"on the start: {result.improved}); design {result.time_s:.0f} s; achieved {result.achieved}",
        flush=True,
    )
    if a.seeds:
        out["validation"] = monte_carlo(dc, result, trials, crit["designed"], a)
    return out


def main(argv=None):
    a = parse(sys.argv[1:] if argv is None else argv)
    import jax

    jax.config.update("jax_enable_x64", True)
    import numpy as np

    import armimp_jax as aj
    from armimp_jax.study import atomic_write_json, stamped

    t0 = time.perf_counter()
    settings = {k: v for k, v in vars(a).items() if k != "out"}
    rows = []
    for c, t in a.cases:  # saved after each case
        rows.append(run_case(aj, np, jax, c, t, a))
        atomic_write_json(a.out, dict(settings=stamped(settings), cases=rows, elapsed_s=time.perf_counter() - t0))
    print(f"total {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
