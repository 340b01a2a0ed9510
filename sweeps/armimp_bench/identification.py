"""What the identification benchmarks compute (``sweeps/bench_identify_coverage.py``,
``bench_identify_efficiency.py``): their cases, the recordings study of each on the study
engine (``study.sweep.coverage.Recordings``), its summary and tables, and issue 27's example of
``identify`` from a generic start (``must_show``).
"""

from __future__ import annotations

import jax
import numpy as np

import armimp_jax as aj
from armimp_jax import presets
from armimp_jax.study.runs.results import atomic_write_json, stamped
from armimp_jax.study.sweep import coverage as cov

ARM = cov.ARM
COVERAGE_CASES = "pd:0.2,pd:1,imbic:0.2,imbic:1"  # bench_identify_coverage's --cases default
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


def friction_law(tau_c, a):
    """The case's friction: LuGre (tau_s = 1.5 tau_c) or CoulombViscous (``--viscous``)."""
    if a.friction == "lugre":
        return aj.LuGre(tau_c, 1.5 * tau_c)
    return aj.CoulombViscous(tau_c, viscous=a.viscous)


def make_truth(controller, tau_c, a):
    """The case's trial: the controller kind at its defaults, the paper's arm at location 2,
    the ``--friction`` law at ``tau_c``, the studies' noise (``a.voluntary`` N of the person's
    force) and ``a.acquisition``."""
    return aj.make_trial(
        aj.kinds.controller_kind(controller)(),
        arm=presets.arm(2),
        friction=friction_law(tau_c, a),
        acquisition=a.acquisition,
        **cov.noise(a.voluntary),
    )


def coverage(a, out, *, console=None) -> dict:
    """The coverage study of options ``a`` (``bench_identify_coverage.py``'s) in run folder
    ``out``: per case ``{seeds: rows, summary}`` (``cov.coverage_summary``), also written to
    ``out/coverage.json`` with the settings."""
    n = int(round(a.seconds * 1000))
    f = aj.perturbation(jax.random.key(2024), n, a.peak)
    names = {f"{c}:{t:g}": (c, t) for c, t in a.cases}
    settings = {k: v for k, v in vars(a).items() if k not in ("out", "seeds", "cases", "must_show")}

    def make(name):
        return make_truth(*names[name], a), f

    def one(truth, f, name, seed):
        return cov.identify_row(truth, f, seed, free=a.free, draws=a.draws)

    def report(name, row):
        return f"  {name} seed {row['seed']}: {row['time_s']:.1f} s, {row['iterations']} steps"

    def finish(run, rows):
        cases = {}
        for name, rs in rows.items():
            truth, _ = make(name)
            cases[name] = dict(seeds=rs, summary=cov.coverage_summary(rs, truth, f, a.free, draws=a.draws))
        atomic_write_json(run.path / "coverage.json", dict(settings=stamped(settings), cases=cases))
        return cases

    spec = cov.Recordings("coverage", settings, list(names), range(a.seeds), make, one, report)
    return cov.run_recordings(spec, out, console=console, finish=finish).finished


def must_show(a) -> dict:
    """Issue 27's example: ``identify`` from a generic arm (and half the free friction) on one
    recording, called twice (the second without compiling); prints and returns what it found."""
    arm = presets.arm(2)
    noise = cov.noise()
    default = [tuple(c.split(":")[:1]) + (float(c.split(":")[1]),) for c in COVERAGE_CASES.split(",")]
    controller, tau_c = a.cases[0] if a.cases != default else ("pd", 0.8)
    ctrl = aj.kinds.controller_kind(controller)()
    truth = aj.make_trial(ctrl, arm=arm, friction=friction_law(tau_c, a), **noise)
    # half the friction where it is estimated; a fixed one keeps its (known) value
    if a.friction == "lugre":
        start_friction = aj.LuGre(tau_c / 2, 0.75 * tau_c if "friction.tau_s" in a.free else 1.5 * tau_c)
    else:
        half = [n.split(".")[1] for n in a.free if n.startswith("friction.")]
        start_friction = aj.CoulombViscous(
            tau_c / (2 if "tau_c" in half else 1), viscous=a.viscous / (2 if "viscous" in half else 1)
        )
    generic = aj.Arm(np.eye(2), 5.0 * np.eye(2), 150.0 * np.eye(2), arm.endpoint)
    start = aj.make_trial(ctrl, arm=generic, friction=start_friction, **noise)
    f = aj.perturbation(jax.random.key(2024), int(round(a.seconds * 1000)), a.peak)
    rec = cov.record(truth, f, 3)
    runs = [aj.identify(start, f, rec.x, rec.fh, free=a.free, draws=a.draws) for _ in range(2)]
    res = runs[1]
    true = cov.truth_of(truth, a.free)
    print(f"converged: {res.converged} {res.message}")
    print(f"intervals reliable: {res.intervals_reliable} {' '.join(res.warnings)}")
    print(
        f"first call (compiling) {runs[0].time_s:.1f} s = {runs[0].time_s / runs[0].forward_s:.0f} forward "
        f"simulations; second {res.time_s:.1f} s = {res.time_s / res.forward_s:.0f} forward simulations of "
        f"{res.forward_s:.3f} s; {res.iterations} Gauss-Newton steps"
    )
    out = dict(
        converged=res.converged,
        message=res.message,
        warnings=res.warnings,
        time_s=res.time_s,
        first_call_time_s=runs[0].time_s,
        forward_s=res.forward_s,
        iterations=res.iterations,
        history=res.history,
        parameters={},
    )
    for n in a.free:
        z = (res.values[n] - true[n]) / res.se[n]
        rel = float(np.linalg.norm(res.values[n] - true[n]) / np.linalg.norm(true[n]))
        print(
            f"{n}: estimate {np.round(res.values[n], 4).tolist()} truth {np.round(true[n], 4).tolist()}\n"
            f"    SE {np.round(res.se[n], 4).tolist()}\n"
            f"    error/SE {np.round(z, 2).tolist()}; relative error (Frobenius) {rel:.3f}"
        )
        out["parameters"][n] = dict(
            estimate=res.values[n].tolist(),
            truth=true[n].tolist(),
            se=res.se[n].tolist(),
            error_over_se=z.tolist(),
            relative_error=rel,
        )
    c = res.classical
    if c is not None:
        for n in ("mass", "damping", "stiffness"):
            rel = float(np.linalg.norm(np.asarray(getattr(c, n)) - true[f"arm.{n}"]) / np.linalg.norm(true[f"arm.{n}"]))
            print(f"classical {n}: {np.round(np.asarray(getattr(c, n)), 3).tolist()}, relative error {rel:.3f}")
            out[f"classical_{n}_relative_error"] = rel
    print(f"VAF position {np.round(res.vaf_position, 2).tolist()} %, force {np.round(res.vaf_force, 2).tolist()} %")
    return out


# --- efficiency against the bound -----------------------------------------------------------


def make_case(name, a):
    """``(truth, f)`` of a case."""
    controller, location, k_rd, tau_c, peak, _, *acquisition = CASES[name]
    ctrl = aj.PD() if controller == "pd" else aj.IMBIC(k_rd=None if k_rd is None else k_rd * np.eye(2))
    truth = aj.make_trial(
        ctrl,
        arm=presets.arm(location),
        friction=aj.LuGre(tau_c, 1.5 * tau_c) if tau_c > 0 else aj.NO_FRICTION,
        acquisition=acquisition[0] if acquisition else "instant",
        **cov.noise(),
    )
    peak = presets.perturbation_peak(1) if peak == "L1" else peak
    return truth, aj.perturbation(jax.random.key(2024), int(round(a.seconds * 1000)), peak)


def free_of(name):
    return ARM + (("friction.tau_c",) if CASES[name][5] == "tau_c" else ())


def efficiency_summary(truth, f, rows, a):
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
        e, s, spread, hit = cov.spread_and_hits(ok, n, true)
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


def efficiency(a, out, *, console=None) -> dict:
    """The efficiency study of options ``a`` (``bench_identify_efficiency.py``'s) in run folder
    ``out``: per case ``{seeds: rows, summary}``, also written to ``out/efficiency.json``."""
    settings = {k: v for k, v in vars(a).items() if k not in ("out", "seeds", "cases", "markdown")}

    def one(truth, f, name, seed):
        return cov.identify_row(truth, f, seed, free=free_of(name), draws=a.draws, statistic=a.statistic)

    def report(name, row):
        return f"  {name} seed {row['seed']}: {row['time_s']:.1f} s, {row['statistic']}"

    def finish(run, rows):
        cases = {}
        for name, rs in rows.items():
            truth, f = make_case(name, a)
            cases[name] = dict(seeds=rs, summary=efficiency_summary(truth, f, rs, a))
        atomic_write_json(run.path / "efficiency.json", dict(settings=stamped(settings), cases=cases))
        return cases

    spec = cov.Recordings("efficiency", settings, a.cases, range(a.seeds), lambda n: make_case(n, a), one, report)
    return cov.run_recordings(spec, out, console=console, finish=finish).finished


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
