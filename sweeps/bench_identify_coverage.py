"""Coverage of identify's 95% intervals over repeated noise draws, the classical route's beside
them, and predict_se against the spread of the estimates (docs/identification.md).

For each case (a controller kind at its defaults: ``pd``, ``imbic``, ``admittance``; a
Coulomb torque tau_c of the ``--friction`` law: LuGre with tau_s = 1.5 tau_c, or
CoulombViscous with ``--viscous``; paper arm at location 2; force noise 0.05 N, 2^18-count
encoders, voluntary force 0.3 N RMS below 2 Hz; ``--acquisition``): one perturbation, then
per seed a recording under new noise, ``aj.identify`` of the arm's 12 entries and the free
friction parameters, started at the truth (the intervals are what is tested here;
``--must-show`` tests the descent from afar), and the classical answer of the same
recording (Welch + ``fit_impedance`` with spectral SEs). Reported per case and parameter:
the share of 95% intervals that cover the truth, the estimates' spread over the mean SE,
their mean error over the spread, ``aj.predict_se`` over the spread, and the spread over
``aj.crlb`` (where the loop has a bound). Results are saved after every seed (``--out``,
strict JSON with the settings and the package version); a rerun with the same settings
resumes where it stopped.

    python sweeps/bench_identify_coverage.py --seeds 100 --seconds 10 --out coverage.json
    python sweeps/bench_identify_coverage.py --must-show --out must_show.json
    python sweeps/bench_identify_coverage.py --cases admittance:0 --free arm --seconds 20 --peak 2.25 --seeds 50
    python sweeps/bench_identify_coverage.py --must-show --friction coulomb_viscous --cases pd:0.06 \
        --free arm,tau_c,viscous
"""

from __future__ import annotations

import functools
import pathlib
import sys
import time

from _cli import Parser, bench_noise, fail, parse_cases, resumable, run_seeds, spread_and_hits

ARM = ("arm.mass", "arm.damping", "arm.stiffness")
DEFAULT_CASES = "pd:0.2,pd:1,imbic:0.2,imbic:1"


def parse(argv):
    p = Parser(prog="bench_identify_coverage", description=__doc__.split("\n\n")[0])
    p.add_argument("--seeds", type=int, default=100, help="recordings (noise draws) per case (default 100)")
    p.add_argument("--seconds", type=float, default=10.0, help="record length [s] (default 10; --must-show: 20)")
    p.add_argument("--peak", type=float, default=10.0, help="perturbation peak [N] per axis (default 10)")
    p.add_argument("--draws", type=int, default=64, help="identify's noise draws (default 64)")
    p.add_argument("--voluntary", type=float, default=0.3, help="voluntary force RMS [N] below 2 Hz (default 0.3)")
    p.add_argument("--acquisition", default="instant", choices=("instant", "interval_mean"))
    p.add_argument("--cases", default=DEFAULT_CASES, help="controller:tau_c list [N m] (--must-show: its first)")
    p.add_argument("--friction", default="lugre", choices=("lugre", "coulomb_viscous"), help="the friction law")
    p.add_argument("--viscous", type=float, default=0.0025, help="coulomb_viscous: viscous [N m s/rad]")
    p.add_argument("--free", default="arm,tau_c", help="arm and the law's parameters (comma list; default arm,tau_c)")
    p.add_argument("--out", default="identify_coverage.json", help="JSON file of the results (resumed if present)")
    p.add_argument("--must-show", action="store_true", help="issue 27's example from a generic start instead")
    a = p.parse_args(argv)
    law = {"lugre": ("tau_c", "tau_s", "sigma0", "sigma1", "sigma2"), "coulomb_viscous": ("tau_c", "viscous")}
    names = {"arm": ARM, **{n: (f"friction.{n}",) for n in law[a.friction]}}
    try:
        a.free = tuple(n for part in a.free.split(",") for n in names[part])
    except KeyError:
        fail(f"--free takes {', '.join(names)} for {a.friction}; got {a.free!r}", p.prog)
    if a.must_show and "--seconds" not in " ".join(argv):
        a.seconds = 20.0
    if a.seeds < 2 or a.seconds < 2 or a.peak <= 0 or a.draws < 8:
        fail("need --seeds >= 2, --seconds >= 2, --peak > 0 and --draws >= 8", p.prog)
    a.cases = parse_cases(a.cases, p.prog, "pd:0.2,imbic:1")
    friction_free = any(n.startswith("friction.") for n in a.free)
    if any(t < 0 or (friction_free and t == 0) for _, t in a.cases):
        fail(f"--cases: tau_c >= 0 (> 0 with friction free); got {a.cases}", p.prog)
    return a


def friction_law(aj, tau_c, a):
    """The case's friction: LuGre (tau_s = 1.5 tau_c) or CoulombViscous (``--viscous``)."""
    if a.friction == "lugre":
        return aj.LuGre(tau_c, 1.5 * tau_c)
    return aj.CoulombViscous(tau_c, viscous=a.viscous)


def make_truth(aj, controller, tau_c, a):
    from armimp_jax import presets

    return aj.make_trial(
        aj.controller_kind(controller)(),
        arm=presets.arm(2),
        friction=friction_law(aj, tau_c, a),
        acquisition=a.acquisition,
        **bench_noise(aj, a.voluntary),
    )


@functools.cache
def simulate(aj, jax):
    """``aj.simulate`` compiled once (a plain call traces the loop anew every time)."""
    return jax.jit(aj.simulate, static_argnames="numerics")


def truth_of(truth, names, np):
    return {n: np.asarray(getattr(getattr(truth, n.split(".")[0]), n.split(".")[1])) for n in names}


def one_seed(aj, np, jax, truth, f, seed, a, free=None, statistic="auto"):
    """identify (of ``free``, default ``a.free``) and the classical fit of one recording (key
    ``10000 + seed``): plain lists, for JSON."""
    rec = simulate(aj, jax)(truth, f, key=jax.random.key(10_000 + seed), numerics=aj.IDENTIFY_NUMERICS)
    if bool(rec.diverged):
        return dict(seed=seed, diverged=True)
    free = a.free if free is None else free
    key = jax.random.key(seed)
    res = aj.identify(truth, f, rec.x, rec.fh, free=free, statistic=statistic, key=key, draws=a.draws)
    out = dict(
        seed=seed,
        diverged=False,
        converged=res.converged,
        reliable=res.intervals_reliable,
        **{k: getattr(res, k) for k in ("not_told", "statistic", "iterations", "time_s")},
        values={n: np.asarray(v).tolist() for n, v in res.values.items()},
        se={n: np.asarray(v).tolist() for n, v in res.se.items()},
    )
    c = res.classical
    if c is not None:
        out["classical"] = {n: np.asarray(getattr(c, n.split(".")[1])).tolist() for n in ARM}
        out["classical_half_width"] = {}
        for n in ARM:
            low, high = c.interval(n.split(".")[1])
            out["classical_half_width"][n] = (0.5 * (np.asarray(high) - np.asarray(low))).tolist()
    return out


def run_case(aj, np, jax, state, group, name, truth, f, opts, *, seeds, path, free=None, statistic="auto", report=None):
    """The recordings ``0 .. seeds - 1`` of case ``name`` in ``state[group]`` that it lacks
    (``_cli.run_seeds``, saved after each), each ``one_seed`` of ``truth`` under ``f``."""

    def one(seed):
        return one_seed(aj, np, jax, truth, f, seed, opts, free, statistic)

    return run_seeds(state, group, name, seeds, one, path, report)


def summarise(np, rows, true, pred, names, bound=None):
    # a fit that did not converge says so and prints no interval: counted here, never scored
    ok = [r for r in rows if not r["diverged"] and r["converged"]]
    out = dict(
        seeds=len(rows),
        recordings=sum(not r["diverged"] for r in rows),
        diverged=sum(bool(r["diverged"]) for r in rows),
        converged=len(ok),
        parameters={},
    )
    hits_all, hits_cls = [], []
    for n in names:
        e, s, spread, hit = spread_and_hits(ok, n, true[n])
        hits_all.append(hit.reshape(len(ok), -1))
        row = dict(
            coverage=hit.mean(axis=0).ravel().tolist(),
            spread_over_se=(spread / s.mean(axis=0)).ravel().tolist(),
            mean_error_over_spread=((e.mean(axis=0) - true[n]) / spread).ravel().tolist(),
            predicted_over_spread=(np.asarray(pred.se[n]) / spread).ravel().tolist(),
        )
        if bound is not None and n in bound.se:
            row["spread_over_bound"] = (spread / np.asarray(bound.se[n])).ravel().tolist()
        if n in ARM and all("classical" in r for r in ok):
            c = np.array([r["classical"][n] for r in ok])
            w = np.array([r["classical_half_width"][n] for r in ok])
            chit = np.abs(c - true[n]) <= w
            hits_cls.append(chit.reshape(len(ok), -1))
            row["classical_coverage"] = chit.mean(axis=0).ravel().tolist()
            row["classical_mean_error_over_spread"] = (
                ((c.mean(axis=0) - true[n]) / c.std(axis=0, ddof=1)).ravel().tolist()
            )
        out["parameters"][n] = row
    out["coverage_all"] = float(np.concatenate(hits_all, axis=1).mean())
    out["classical_coverage_arm"] = float(np.concatenate(hits_cls, axis=1).mean()) if hits_cls else None
    out["mean_time_s"] = float(np.mean([r["time_s"] for r in ok]))
    return out


def run_cases(aj, np, jax, a, settings):
    from armimp_jax.study import atomic_write_json

    path = pathlib.Path(a.out)
    state = resumable(path, settings, "bench_identify_coverage", cases={})
    n = int(round(a.seconds * 1000))
    f = aj.perturbation(jax.random.key(2024), n, a.peak)
    for controller, tau_c in a.cases:
        name = f"{controller}:{tau_c:g}"
        truth = make_truth(aj, controller, tau_c, a)
        case = run_case(
            *(aj, np, jax, state, "cases", name, truth, f, a),
            seeds=a.seeds,
            path=path,
            report=lambda seed, row: f"  {name} seed {seed}: {row['time_s']:.1f} s, {row['iterations']} steps",  # noqa: B023
        )
        if "summary" not in case or case["summary"].get("seeds") != len(case["seeds"]):
            pred = aj.predict_se(truth, f, free=a.free, draws=a.draws)
            arm_free = tuple(n for n in a.free if n in ARM)
            bound = aj.crlb(truth, f, free=arm_free) if arm_free else None
            bound = bound if bound is not None and bound.near_linear else None
            case["summary"] = summarise(np, case["seeds"], truth_of(truth, a.free, np), pred, a.free, bound)
            atomic_write_json(path, state)
    return state


def print_table(state, a):
    print(f"\ncoverage of 95% intervals, {a.seeds} seeds, {a.seconds:g} s records, peak {a.peak:g} N, {a.acquisition}")
    print(
        f"{'case':<14}{'parameter':<18}{'coverage (per entry)':<28}{'spread/SE':<22}{'pred/spread':<22}"
        f"{'spread/bound':<22}classical"
    )
    for name, case in state["cases"].items():
        s = case["summary"]
        for n, r in s["parameters"].items():
            cls = " ".join(f"{v:.2f}" for v in r.get("classical_coverage", []))
            bound = " ".join(f"{v:.2f}" for v in r.get("spread_over_bound", []))
            print(
                f"{name:<14}{n:<18}{' '.join(f'{v:.2f}' for v in r['coverage']):<28}"
                f"{' '.join(f'{v:.2f}' for v in r['spread_over_se']):<22}"
                f"{' '.join(f'{v:.2f}' for v in r['predicted_over_spread']):<22}{bound:<22}{cls}"
            )
        cls_all = s["classical_coverage_arm"]
        print(
            f"{'':<14}{'all':<18}{s['coverage_all']:.3f}  (classical, arm: "
            f"{'-' if cls_all is None else format(cls_all, '.3f')}); converged {s['converged']}/{s['recordings']}, "
            f"{s['mean_time_s']:.1f} s per identify"
        )


def must_show(aj, np, jax, a):
    from armimp_jax import presets

    arm = presets.arm(2)
    noise = bench_noise(aj)
    controller, tau_c = a.cases[0] if a.cases != parse_cases(DEFAULT_CASES, "", "") else ("pd", 0.8)
    ctrl = aj.controller_kind(controller)()
    truth = aj.make_trial(ctrl, arm=arm, friction=friction_law(aj, tau_c, a), **noise)
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
    rec = simulate(aj, jax)(truth, f, key=jax.random.key(3), numerics=aj.IDENTIFY_NUMERICS)
    runs = [aj.identify(start, f, rec.x, rec.fh, free=a.free, draws=a.draws) for _ in range(2)]
    res = runs[1]
    true = truth_of(truth, a.free, np)
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


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    a = parse(argv)
    import jax

    jax.config.update("jax_enable_x64", True)
    import numpy as np

    import armimp_jax as aj
    from armimp_jax.study import atomic_write_json, stamped

    t0 = time.perf_counter()
    for controller, _ in a.cases:  # a controller kind (one line naming the known ones if not)
        try:
            aj.controller_kind(controller)
        except ValueError as err:
            fail(f"--cases: {err}", "bench_identify_coverage")
    settings = {k: v for k, v in vars(a).items() if k != "out"}
    if a.must_show:
        atomic_write_json(a.out, dict(settings=stamped(settings), must_show=must_show(aj, np, jax, a)))
        return
    state = run_cases(aj, np, jax, a, settings)
    print_table(state, a)
    print(f"total {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
