"""What the design benchmarks compute: ``aj.design`` against the paper's perturbation and
the flat noise, checked by Monte Carlo (``sweeps/bench_design.py``); what PD's gains do for
identification through friction (``bench_pd_gains.py``); a design on the bound checked by
Monte Carlo identification at each arm (``bench_design_bound.py``, on the study engine:
``study.sweep.coverage.Recordings``, resumable).
"""

from __future__ import annotations

import json
import pathlib
import time

import jax
import numpy as np

import armimp_jax as aj
from armimp_jax import paper
from armimp_jax._identification.precision import record_minutes
from armimp_jax.study.design import design_check as dc
from armimp_jax.study.design import design_experiment as dx
from armimp_jax.study.runs.results import atomic_write_json, stamped
from armimp_jax.study.sweep import coverage as cov

ARM = cov.ARM
TARGETS = [f"arm.{n}[{i},{i}]" for n in ("mass", "damping", "stiffness") for i in (0, 1)]
FREE = ARM
Z95 = cov.Z95


def criterion(dx, preds, trials):
    """The largest relative SE over the targets and the trials, and per trial per target."""
    per = [dx.relative_se(pred, t, free=FREE, targets=TARGETS) for pred, t in zip(preds, trials)]
    return max(max(r.values()) for r in per), per


def make_case(controller, tau_c, a):
    """``(trials, paper_signal, limits, knots)`` of one case: the four arms, the paper's level-1
    perturbation (key 2024), the limits at its RMS and peak, and the ShapedNoise knots [Hz]."""
    trials = [
        aj.make_trial(
            aj.PD() if controller == "pd" else aj.IMBIC(),
            arm=paper.arm(loc),
            friction=aj.LuGre(tau_c, 1.5 * tau_c),
            **cov.noise(),
        )
        for loc in (1, 2, 3, 4)
    ]
    n = int(round(a.record * 1000))
    paper_signal = np.asarray(aj.signals.PaperNoise(paper.perturbation_peak(1)).signal(jax.random.key(2024), n))
    rms = np.sqrt(np.mean(paper_signal**2, axis=0))
    limits = aj.experiment.Limits(
        rms_force=tuple(rms), peak_force=2.25, record=a.record, peak_displacement=a.displacement
    )
    return trials, paper_signal, limits, np.geomspace(a.low, 15.0, a.knots)


def run_design(trials, limits, knots, a, name):
    """``aj.design`` from one flat ShapedNoise start per ``--duty``, printing each step."""
    starts = [aj.signals.ShapedNoise(knots, np.ones((2, a.knots)), 1.0, duty=d, burst=a.burst) for d in a.duty]
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
        method=aj.experiment.MonteCarlo(draws=a.draws),
        learning_rate=a.learning_rate,
        progress=progress,
    )


def compare(dx, result, trials, paper_signal, limits, knots, a) -> dict:
    """``{signal: (criterion, per trial per target)}`` predicted for the paper's perturbation,
    the flat continuous noise, the design's start and the design, all on the same draws (key 0)."""
    flat = aj.signals.ShapedNoise(knots, np.ones((2, a.knots)), 1.0)
    flat_signal = aj.signals.limited_signal(flat, limits, key=jax.random.split(jax.random.key(0))[0], trials=trials)
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


def design_case(controller, tau_c, a):
    """One case: the design, its comparison with the other signals and (``--seeds``) its check."""
    trials, paper_signal, limits, knots = make_case(controller, tau_c, a)
    result = run_design(trials, limits, knots, a, f"{controller} {tau_c:g}")
    crit = compare(dx, result, trials, paper_signal, limits, knots, a)
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


# --- PD's gains ------------------------------------------------------------------------------


def one_pair(kp: float, kv: float, a) -> dict:
    """The drift, the limited signal's RMS and peak, and per arm the largest relative SE."""
    control = aj.PD(kp=kp * np.eye(2), kv=kv * np.eye(2))
    trials = [
        aj.make_trial(control, arm=paper.arm(loc), friction=aj.LuGre(a.tau_c, 1.5 * a.tau_c), **cov.noise())
        for loc in a.arms
    ]
    n = int(round(a.record * 1000))
    level1 = np.asarray(aj.signals.PaperNoise(paper.perturbation_peak(1)).signal(jax.random.key(2024), n))
    limits = aj.experiment.Limits(
        rms_force=tuple(np.sqrt(np.mean(level1**2, axis=0))),
        peak_force=2.25,
        record=a.record,
        peak_displacement=a.displacement,
    )
    knots = np.geomspace(a.low, a.high, a.knots)
    family = aj.signals.ShapedNoise(knots, np.ones((2, a.knots)), 1.0, duty=a.duty, burst=a.burst)
    signal = np.asarray(aj.signals.limited_signal(family, limits, key=jax.random.key(0), trials=trials))
    worst = []
    for t in trials:
        rel = dx.relative_se(aj.predict_se(t, signal, free=FREE, draws=a.draws), t, free=FREE, targets=TARGETS)
        label = max(rel, key=rel.get)
        worst.append(dict(relative_se=float(rel[label]), entry=label))
    largest = max(w["relative_se"] for w in worst)
    return dict(
        kp=kp,
        kv=kv,
        drift_mm=[1e3 * float(aj.linear.drift(t)) for t in trials],
        rms_force=np.sqrt(np.mean(signal**2, axis=0)).tolist(),
        peak_force=np.abs(signal).max(axis=0).tolist(),
        worst=worst,
        minutes=record_minutes(a.record, largest, a.precision),
    )


# --- a design on the bound, checked by Monte Carlo ------------------------------------------


def designed_trials(design_dir: pathlib.Path):
    """``(doc, trials, f)``: design.json, the robust set's trials with the designed controller, and
    the perturbation ``(N, 2)`` [N]."""
    doc = json.loads((design_dir / "design.json").read_text())
    if doc.get("method") != "bound":
        raise ValueError(f"{design_dir}/design.json is not a design on the bound (method {doc.get('method')!r})")
    config = doc["settings"]["config"]
    config["controller"].update({k: v for k, v in doc["controller"].items() if k != "type"})
    trials = dx.build_design(config, where=str(design_dir))[0]
    f = np.loadtxt(design_dir / "perturbation.csv", delimiter=",", skiprows=1)
    return doc, trials, f


def summarise(rows, trial, row_doc, targets):
    ok = [r for r in rows if not r["diverged"] and r["converged"]]
    rel_spread, rel_bound, out = [], [], dict(seeds=len(rows), converged=len(ok), entries={})
    se_bound = dict(zip([f"{n}[{i},{j}]" for n in ARM for i in range(2) for j in range(2)], row_doc["se_after"]))
    hits = []
    for n in ARM:
        true = np.asarray(getattr(trial.arm, n.split(".")[1]))
        _, _, spread, hit = cov.spread_and_hits(ok, n, true)
        hits.append(hit.reshape(len(ok), -1))
        for i in range(2):
            label = f"{n}[{i},{i}]"
            b = se_bound[label]
            out["entries"][label] = dict(
                bound=b, spread=float(spread[i, i]), ratio=float(spread[i, i] / b), coverage=float(hit[:, i, i].mean())
            )
            if label in targets:
                rel_spread.append(spread[i, i] / abs(true[i, i]))
                rel_bound.append(b / abs(true[i, i]))
    out["coverage_all"] = float(np.concatenate(hits, axis=1).mean())
    out["largest_relative_spread"] = float(max(rel_spread))
    out["largest_relative_bound"] = float(max(rel_bound))
    out["achieved_over_predicted"] = out["largest_relative_spread"] / out["largest_relative_bound"]
    out["minutes_bound"] = row_doc["minutes_after"]
    out["minutes_monte_carlo"] = row_doc["minutes_after"] * out["achieved_over_predicted"] ** 2
    return out


def print_markdown(state):
    print("| arm | entry | bound | spread | spread / bound | coverage |")
    print("|---|---|---|---|---|---|")
    for name, case in state["arms"].items():
        s = case.get("summary")
        if s is None:
            print(f"| {name} | (unfinished: resume the run) | | | | |")
            continue
        for label, r in s["entries"].items():
            print(
                f"| {name} | `{label}` | {r['bound']:.4g} | {r['spread']:.4g} | {r['ratio']:.2f} | "
                f"{r['coverage']:.2f} |"
            )
        print(
            f"| | **largest relative spread {s['largest_relative_spread']:.4f} / bound "
            f"{s['largest_relative_bound']:.4f} = {s['achieved_over_predicted']:.2f}** | minutes: bound "
            f"{s['minutes_bound']:.2f}, Monte Carlo {s['minutes_monte_carlo']:.2f} | converged {s['converged']}/"
            f"{s['seeds']} | | coverage {s['coverage_all']:.3f} |"
        )


def merge(a, doc, trials, states):
    """One state of several runs' recordings (each seed once), the summaries recomputed."""
    from armimp_jax.study import atomic_write_json

    designs = {st["settings"]["design_time"] for st in states}
    if len(designs) != 1:
        raise ValueError("--merge: the runs are of different designs (their design times differ)")
    robust = doc["settings"]["config"]["design"]["robust"] or [0]
    merged = dict(settings=dict(states[0]["settings"], merged=[str(m) for m in a.merge]), arms={})
    for k, loc in enumerate(robust):
        name = f"arm at location {loc}"
        rows = {r["recording"]: r for st in states for r in st["arms"].get(name, {}).get("seeds", [])}
        if len(rows) < 2:
            continue
        seeds = [rows[s] for s in sorted(rows)]
        merged["arms"][name] = dict(seeds=seeds, summary=summarise(seeds, trials[k], doc["trials"][k], doc["targets"]))
    pathlib.Path(a.out).mkdir(parents=True, exist_ok=True)
    atomic_write_json(pathlib.Path(a.out) / "design_bound.json", merged)
    print_markdown(merged)


def check_bound_design(a, out, *, console=None) -> dict:
    """``a.seeds`` recordings per arm of the design in ``a.design`` (from seed ``a.first``), each
    identified from the truth, on the study engine in run folder ``out``; per arm ``{seeds:
    rows, summary}``, also written to ``out/design_bound.json``."""
    doc, trials, f = designed_trials(a.design)
    robust = doc["settings"]["config"]["design"]["robust"] or [0]
    arms = range(1, len(trials) + 1) if a.arms is None else [int(k) for k in a.arms.split(",")]
    bad = [k for k in arms if not 1 <= k <= len(trials)]
    if bad:
        raise ValueError(f"--arms {bad[0]} is outside the design's 1..{len(trials)}")
    names = {f"arm at location {robust[k - 1]}": k - 1 for k in arms}
    settings = dict(design=str(a.design), design_time=doc["time_s"])

    def one(trial, f, name, seed):
        row = cov.identify_row(trial, f, seed, free=ARM, draws=32, offset=70_000)
        return row | dict(recording=seed)

    def report(name, row):
        return f"  {name} seed {row['seed']}: {row['time_s']:.1f} s, converged {row['converged']}"

    def finish(run, rows):
        state = dict(settings=stamped(settings), arms={})
        for name, rs in rows.items():
            k = names[name]
            state["arms"][name] = dict(seeds=rs, summary=summarise(rs, trials[k], doc["trials"][k], doc["targets"]))
        atomic_write_json(run.path / "design_bound.json", state)
        return state

    seeds = range(a.first, a.first + a.seeds)
    spec = cov.Recordings("design_bound", settings, list(names), seeds, lambda n: (trials[names[n]], f), one, report)
    return cov.run_recordings(spec, out, console=console, finish=finish).finished
