"""identify's efficiency against the Cramér-Rao bound, and its coverage, over repeated recordings
(docs/identification.md, the efficiency table).

Per case (controller, paper arm location, IMBIC's desired stiffness, Coulomb torque with
stiction 1.5 times it, perturbation): force noise 0.05 N, 2^18-count encoders, the person's
force 0.3 N RMS below 2 Hz, one perturbation (key 2024), then per seed a recording under new
noise and ``aj.identify`` of the arm's 12 entries from the truth (the intervals and the
spread are what is measured). Per case and entry: the bound (``aj.crlb``; of the loop
without friction, which is what IMBIC promises to leave; none through stick-slip),
``aj.predict_se``, the estimates' spread, spread / bound, and the share of 95% intervals
that hold the truth. Results are saved after every recording (``--out``, strict JSON with
the settings and the package version); a rerun with the same settings resumes.

    python sweeps/bench_identify_efficiency.py --seeds 50 --out efficiency.json
    python sweeps/bench_identify_efficiency.py --statistic welch --out efficiency_welch.json
"""

from __future__ import annotations

import pathlib
import sys
import time

from _cli import Parser, bench_noise, fail, resumable, spread_and_hits
from bench_identify_coverage import run_case

ARM = ("arm.mass", "arm.damping", "arm.stiffness")
# name: (controller, arm location, IMBIC's k_rd [N/m] or None for the paper's, tau_c [N m], peak [N] or "L1",
# free: the arm's matrices, and the Coulomb torque too with "tau_c"; optionally the acquisition, default instant)
CASES = {
    "imbic-a2": ("imbic", 2, None, 0.0, "L1", "arm"),
    "imbic-a2-k80": ("imbic", 2, 80.0, 0.0, "L1", "arm"),
    "imbic-a4-k80-1Nm": ("imbic", 4, 80.0, 1.0, "L1", "arm"),
    "pd-a2": ("pd", 2, None, 0.0, "L1", "arm"),
    "pd-a2-0.3Nm": ("pd", 2, None, 0.3, 10.0, "arm"),
    "pd-a2-1Nm": ("pd", 2, None, 1.0, 10.0, "arm"),
    "imbic-a2-0.3Nm-tau_c-free": ("imbic", 2, None, 0.3, "L1", "tau_c"),
    "imbic-a4-k80-1Nm-mean": ("imbic", 4, 80.0, 1.0, "L1", "arm", "interval_mean"),
}
DEFAULT_CASES = tuple(CASES)[:6]
DIAGONAL = ((0, 0), (1, 1))


def parse(argv):
    p = Parser(prog="bench_identify_efficiency", description=__doc__.split("\n\n")[0])
    p.add_argument("--seeds", type=int, default=50, help="recordings per case (default 50)")
    p.add_argument("--seconds", type=float, default=20.0, help="record length [s] (default 20)")
    p.add_argument("--draws", type=int, default=64, help="identify's noise draws (default 64)")
    p.add_argument("--statistic", default="auto", choices=("auto", "efficient", "welch"), help="identify's")
    p.add_argument("--cases", default=",".join(DEFAULT_CASES), help=f"comma list of {', '.join(CASES)}")
    p.add_argument("--out", default="identify_efficiency.json", help="JSON file of the results (resumed if present)")
    p.add_argument("--markdown", action="store_true", help="print the saved results as a Markdown table (no runs)")
    a = p.parse_args(argv)
    a.cases = a.cases.split(",")
    unknown = [c for c in a.cases if c not in CASES]
    if unknown:
        fail(f"--cases: unknown {unknown}; known: {', '.join(CASES)}", p.prog)
    if a.seeds < 3 or a.seconds < 2 or a.draws < 8:
        fail("need --seeds >= 3, --seconds >= 2 and --draws >= 8", p.prog)
    return a


def make_case(aj, np, jax, name, a):
    """``(truth, f)`` of a case."""
    from armimp_jax import presets

    controller, location, k_rd, tau_c, peak, _, *acquisition = CASES[name]
    ctrl = aj.PD() if controller == "pd" else aj.IMBIC(k_rd=None if k_rd is None else k_rd * np.eye(2))
    truth = aj.make_trial(
        ctrl,
        arm=presets.arm(location),
        friction=aj.LuGre(tau_c, 1.5 * tau_c) if tau_c > 0 else aj.NO_FRICTION,
        acquisition=acquisition[0] if acquisition else "instant",
        **bench_noise(aj),
    )
    peak = presets.perturbation_peak(1) if peak == "L1" else peak
    return truth, aj.perturbation(jax.random.key(2024), int(round(a.seconds * 1000)), peak)


def free_of(name):
    return ARM + (("friction.tau_c",) if CASES[name][5] == "tau_c" else ())


def summarise(aj, np, truth, f, rows, a):
    """Per entry: bound, predict_se, spread, spread/bound, coverage; pooled coverage."""
    ok = [r for r in rows if not r["diverged"] and r["converged"]]
    bound = aj.crlb(truth, f)
    pred = aj.predict_se(truth, f, free=ARM, statistic=a.statistic, draws=a.draws)
    # the classical statistic's prediction: what identify gave before the efficient one
    welch = aj.predict_se(truth, f, free=ARM, statistic="welch", draws=a.draws)
    out = dict(
        seeds=len(rows),
        diverged=sum(bool(r["diverged"]) for r in rows),
        converged=len(ok),
        statistics=sorted({r["statistic"] for r in ok}),
        near_linear=bound.near_linear,
        bound_message=bound.message,
        mean_time_s=float(np.mean([r["time_s"] for r in ok])),
        not_told=sorted({e for r in ok for e in r.get("not_told", [])}),
        flagged_share=float(np.mean([bool(r.get("not_told")) for r in ok])),
        parameters={},
    )
    hits = []
    for n in ARM:
        true = np.asarray(getattr(truth.arm, n.split(".")[1]))
        e, s, spread, hit = spread_and_hits(ok, n, true)
        hits.append(hit.reshape(len(ok), -1))
        b = np.asarray(bound.se[n])
        out["parameters"][n] = dict(
            bound=b.tolist(),
            predicted=np.asarray(pred.se[n]).tolist(),
            predicted_welch=np.asarray(welch.se[n]).tolist(),
            spread=spread.tolist(),
            spread_over_bound=(spread / b).tolist(),
            mean_se_over_spread=(s.mean(axis=0) / spread).tolist(),
            mean_error_over_spread=((e.mean(axis=0) - true) / spread).tolist(),
            coverage=hit.mean(axis=0).tolist(),
        )
    out["coverage_all"] = float(np.concatenate(hits, axis=1).mean())  # the arm's 12 entries
    return out


def run_cases(aj, np, jax, a, settings):
    from armimp_jax.study import atomic_write_json

    path = pathlib.Path(a.out)
    state = resumable(path, settings, "bench_identify_efficiency", cases={})
    for name in a.cases:
        truth, f = make_case(aj, np, jax, name, a)
        case = run_case(
            *(aj, np, jax, state, "cases", name, truth, f, a),
            seeds=a.seeds,
            path=path,
            free=free_of(name),
            statistic=a.statistic,
            report=lambda seed, row: f"  {name} seed {seed}: {row['time_s']:.1f} s, {row['statistic']}",  # noqa: B023
        )
        if "summary" not in case or case["summary"].get("seeds") != len(case["seeds"]):
            case["summary"] = summarise(aj, np, truth, f, case["seeds"], a)
            atomic_write_json(path, state)
    return state


def diagonal_entries(state):
    """Per case of ``state``: ``(name, summary, [(label, parameter's row, i, j)])`` over the
    diagonal entries; the summary ``None`` for a case interrupted before it finished
    (resuming completes it)."""
    for name, case in state["cases"].items():
        s = case.get("summary")
        params = {} if s is None else s["parameters"]
        yield name, s, [(f"{n}[{i},{j}]", r, i, j) for n, r in params.items() for i, j in DIAGONAL]


def print_table(state, a):
    print(f"\n{a.seeds} recordings per case, {a.seconds:g} s, statistic {a.statistic}")
    print(
        f"{'case':<18}{'entry':<22}{'bound':>10}{'predict_se':>12}{'spread':>10}{'spread/bound':>14}{'coverage':>10}"
        f"{'welch/bound':>13}"
    )
    for name, s, entries in diagonal_entries(state):
        if s is None:
            print(f"{name:<18}(unfinished: resume the run)")
            continue
        for label, r, i, j in entries:
            print(
                f"{name:<18}{label:<22}{r['bound'][i][j]:>10.4g}{r['predicted'][i][j]:>12.4g}"
                f"{r['spread'][i][j]:>10.4g}{r['spread_over_bound'][i][j]:>14.2f}{r['coverage'][i][j]:>10.2f}"
                f"{r['predicted_welch'][i][j] / r['bound'][i][j]:>13.2f}"
            )
        print(
            f"{'':<18}coverage of all 12 entries {s['coverage_all']:.3f}; converged {s['converged']}/{s['seeds']}; "
            f"{', '.join(s['statistics'])}; {s['mean_time_s']:.1f} s per identify"
            + (f"; not told (flagged in {s['flagged_share']:.0%}): {', '.join(s['not_told'])}" if s["not_told"] else "")
            + ("" if s["near_linear"] else "; no bound: " + s["bound_message"].split(":")[0])
        )


def print_markdown(state):
    """The saved results as docs/identification.md's table."""
    print("| case | entry | bound | predict_se | spread | spread / bound | coverage | classical predicted / bound |")
    print("|---|---|---|---|---|---|---|---|")
    for name, s, entries in diagonal_entries(state):
        if s is None:
            print(f"| {name} | (unfinished: resume the run) | | | | | | |")
            continue
        for label, r, i, j in entries:
            b = r["bound"][i][j]  # None (strict JSON's NaN) where no bound holds
            cells = [
                "-" if b is None else f"{b:.4g}",
                f"{r['predicted'][i][j]:.4g}",
                f"{r['spread'][i][j]:.4g}",
                "-" if b is None else f"{r['spread_over_bound'][i][j]:.2f}",
                f"{r['coverage'][i][j]:.2f}",
                "-" if b is None else f"{r['predicted_welch'][i][j] / b:.2f}",
            ]
            print(f"| {name} | `{label}` | {' | '.join(cells)} |")
        extra = f"; not told: {', '.join(s['not_told'])} in {s['flagged_share']:.0%}" if s.get("not_told") else ""
        print(
            f"| | **all 12 entries** | | | | | **{s['coverage_all']:.3f}** | converged {s['converged']}/{s['seeds']}, "
            f"{', '.join(s['statistics'])}, {s['mean_time_s']:.1f} s{extra} |"
        )


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    a = parse(argv)
    if a.markdown:
        from armimp_jax.study import read_json

        print_markdown(read_json(pathlib.Path(a.out)))
        return
    import jax

    jax.config.update("jax_enable_x64", True)
    import numpy as np

    import armimp_jax as aj

    t0 = time.perf_counter()
    settings = {k: v for k, v in vars(a).items() if k != "out"}
    state = run_cases(aj, np, jax, a, settings)
    print_table(state, a)
    print(f"total {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
