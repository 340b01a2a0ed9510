"""Coverage of identify's 95% intervals over repeated noise draws, and predict_se against the
spread of the estimates (docs/identification.md).

For each case (PD or IMBIC, Coulomb torque tau_c with tau_s = 1.5 tau_c; paper arm at
location 2; force noise 0.05 N, 2^18-count encoders, voluntary force 0.3 N RMS below 2 Hz):
one perturbation, then per seed a recording under new noise and ``aj.identify`` (of the arm,
and of tau_c under PD) started at
the truth (the intervals are what is tested here, not the descent from afar). Reported per
case and parameter group: the share of 95% intervals that cover the truth with the
bootstrap SEs (``se``) and with the textbook Gauss-Newton SEs (``se_textbook``); the
spread of the estimates over the mean reported SE; and ``aj.predict_se`` over that spread.
Fixed seeds; prints the table and saves it as JSON (``--out``).

``--must-show`` runs the issue's example instead: PD, location 2, LuGre 0.8 / 1.2 N m, the
noise above, a 20 s recording, identify from a generic start (M = I kg, B = 5 I N s/m,
K = 150 I N/m, half the friction), each free parameter against the truth in SEs.

    python sweeps/bench_identify_coverage.py --seeds 100 --seconds 20 --out coverage.json
    python sweeps/bench_identify_coverage.py --must-show --free arm,tau_c --out must_show.json
"""

from __future__ import annotations

import math
import sys
import time

from _cli import Parser, fail

ARM = ("arm.mass", "arm.damping", "arm.stiffness")
# IMBIC compensates the friction: its recordings carry almost nothing on tau_c (a free tau_c
# ran to zero), so only PD cases estimate it
GROUPS = {"pd": ARM + ("friction.tau_c",), "imbic": ARM}


def parse(argv):
    p = Parser(prog="bench_identify_coverage", description=__doc__.split("\n\n")[0])
    p.add_argument("--seeds", type=int, default=100, help="recordings (noise draws) per case (default 100)")
    p.add_argument("--seconds", type=float, default=20.0, help="record length [s] (default 20)")
    p.add_argument("--peak", type=float, default=10.0, help="perturbation peak [N] per axis (default 10)")
    p.add_argument("--bootstrap", type=int, default=100, help="identify's bootstrap draws (default 100)")
    p.add_argument("--noise-order", type=int, default=0, help="identify's noise_order (default 0: output error)")
    p.add_argument("--band", default=None, help="identify's band LOW,HIGH [Hz] (default none: every frequency)")
    p.add_argument("--voluntary", type=float, default=0.3, help="voluntary force RMS [N] below 2 Hz (default 0.3)")
    p.add_argument("--cases", default="pd:0.2,pd:1,imbic:0.2,imbic:1", help="controller:tau_c list [N m]")
    p.add_argument("--out", default="identify_coverage.json", help="JSON file of the table")
    p.add_argument("--must-show", action="store_true", help="the issue's example from a generic start instead")
    p.add_argument("--free", default="arm,tau_c", help="--must-show: arm, tau_c, tau_s (comma list; default arm,tau_c)")
    a = p.parse_args(argv)
    names = {
        "arm": ("arm.mass", "arm.damping", "arm.stiffness"),
        "tau_c": ("friction.tau_c",),
        "tau_s": ("friction.tau_s",),
    }
    try:
        a.free = tuple(n for part in a.free.split(",") for n in names[part])
    except KeyError:
        fail(f"--free takes arm, tau_c, tau_s; got {a.free!r}", p.prog)
    try:
        a.band = None if a.band is None else tuple(float(b) for b in a.band.split(","))
    except ValueError:
        fail(f"--band must look like 3,25; got {a.band!r}", p.prog)
    if a.seeds < 2 or a.seconds < 1 or a.peak <= 0 or a.bootstrap < 10:
        fail("need --seeds >= 2, --seconds >= 1, --peak > 0 and --bootstrap >= 10", p.prog)
    try:
        a.cases = [(c.split(":")[0], float(c.split(":")[1])) for c in a.cases.split(",")]
    except (IndexError, ValueError):
        fail(f"--cases must look like pd:0.2,imbic:1; got {a.cases!r}", p.prog)
    if any(c not in ("pd", "imbic") or t <= 0 for c, t in a.cases):
        fail(f"--cases: controller pd or imbic and tau_c > 0; got {a.cases}", p.prog)
    return a


def run_case(aj, np, jax, controller, tau_c, a):
    from armimp_jax import presets

    arm = presets.arm(2)
    truth = aj.make_trial(
        aj.PD() if controller == "pd" else aj.IMBIC(),
        arm=arm,
        friction=aj.LuGre(tau_c, 1.5 * tau_c),
        sensors=aj.Sensors(force_noise=0.05, encoder_counts=2**18),
        voluntary=aj.VoluntaryForce(a.voluntary, 2.0),
    )
    n = int(round(a.seconds * 1000))
    f = aj.perturbation(jax.random.key(2024), n, a.peak)
    true = {
        "arm.mass": np.asarray(arm.mass),
        "arm.damping": np.asarray(arm.damping),
        "arm.stiffness": np.asarray(arm.stiffness),
        "friction.tau_c": np.asarray(truth.friction.tau_c),
    }
    groups = GROUPS[controller]
    est, se, se_tb, ok, times, reliable, linearity = [], [], [], [], [], [], []
    for seed in range(a.seeds):
        rec = aj.simulate(truth, f, key=jax.random.key(10_000 + seed), numerics=aj.IDENTIFY_NUMERICS)
        if bool(rec.diverged):
            continue
        res = aj.identify(
            truth,
            f,
            rec.x,
            rec.fh,
            free=groups,
            key=jax.random.key(seed),
            bootstrap=a.bootstrap,
            noise_order=a.noise_order,
            band=a.band,
        )
        est.append({g: res.values[g] for g in groups})
        se.append({g: res.se[g] for g in groups})
        se_tb.append({g: res.se_textbook[g] for g in groups})
        ok.append(res.converged)
        reliable.append(res.intervals_reliable)
        linearity.append(res.linearity)
        times.append(res.time_s)
        print(
            f"  {controller} tau_c={tau_c:g} seed {seed}: {res.time_s:.1f} s, converged={res.converged}, "
            f"linearity {res.linearity:.2f} SE",
            flush=True,
        )
    pred = aj.predict_se(truth, f, free=groups, bootstrap=a.bootstrap, noise_order=a.noise_order, band=a.band)
    z = 1.959963984540054
    out = dict(
        controller=controller,
        tau_c=tau_c,
        recordings=len(est),
        converged=int(sum(ok)),
        reliable=int(sum(reliable)),
        median_linearity=float(np.median(linearity)),
        mean_time_s=float(np.mean(times)),
        groups={},
    )
    for g in groups:
        e = np.stack([r[g] for r in est])
        s = np.stack([r[g] for r in se])
        t = np.stack([r[g] for r in se_tb])
        spread = e.std(axis=0, ddof=1)
        out["groups"][g] = dict(
            coverage=float(np.mean(np.abs(e - true[g]) <= z * s)),
            coverage_textbook=float(np.mean(np.abs(e - true[g]) <= z * t)),
            spread_over_se=float(np.median(spread / s.mean(axis=0))),
            predicted_over_spread=float(np.median(np.asarray(pred.se[g]) / spread)),
            mean_error_over_spread=float(np.median(np.abs(e.mean(axis=0) - true[g]) / spread)),
        )
    cov = [np.abs(np.stack([r[g] for r in est]) - true[g]) <= z * np.stack([r[g] for r in se]) for g in groups]
    hits = np.concatenate([c.reshape(len(est), -1) for c in cov], axis=1)
    out["coverage_all"] = float(np.mean(hits))
    flagged = ~np.asarray(reliable)
    out["coverage_flagged"] = float(np.mean(hits[flagged])) if flagged.any() else None
    out["coverage_reliable"] = float(np.mean(hits[~flagged])) if (~flagged).any() else None
    return out


def must_show(aj, np, jax, a):
    from armimp_jax import presets

    arm = presets.arm(2)
    noise = dict(sensors=aj.Sensors(force_noise=0.05, encoder_counts=2**18), voluntary=aj.VoluntaryForce(0.3, 2.0))
    truth = aj.make_trial(aj.PD(), arm=arm, friction=aj.LuGre(0.8, 1.2), **noise)
    # half the friction where it is estimated; a fixed tau_s keeps its (known) value
    start_friction = aj.LuGre(0.4, 0.6 if "friction.tau_s" in a.free else 1.2)
    generic = aj.Arm(np.eye(2), 5.0 * np.eye(2), 150.0 * np.eye(2), arm.endpoint)
    start = aj.make_trial(aj.PD(), arm=generic, friction=start_friction, **noise)
    f = aj.perturbation(jax.random.key(2024), int(round(a.seconds * 1000)), a.peak)
    rec = aj.simulate(truth, f, key=jax.random.key(3), numerics=aj.IDENTIFY_NUMERICS)
    res = aj.identify(
        start, f, rec.x, rec.fh, free=a.free, bootstrap=a.bootstrap, noise_order=a.noise_order, band=a.band
    )
    true = {n: np.asarray(getattr(getattr(truth, n.split(".")[0]), n.split(".")[1])) for n in a.free}
    print(f"converged: {res.converged} {res.message}")
    print(f"intervals reliable: {res.intervals_reliable} (linearity {res.linearity:.2f} SE) {' '.join(res.warnings)}")
    print(
        f"{res.time_s:.0f} s = {res.time_s / res.forward_s:.0f} forward simulations of {res.forward_s:.3f} s; "
        f"{res.iterations} solver steps"
    )
    out = dict(
        converged=res.converged,
        message=res.message,
        intervals_reliable=res.intervals_reliable,
        linearity=res.linearity,
        warnings=res.warnings,
        time_s=res.time_s,
        forward_s=res.forward_s,
        iterations=res.iterations,
        parameters={},
    )
    for n in a.free:
        z = (res.values[n] - true[n]) / res.se[n]
        rel = float(np.linalg.norm(res.values[n] - true[n]) / np.linalg.norm(true[n]))
        print(
            f"{n}: estimate {np.round(res.values[n], 4).tolist()} truth {np.round(true[n], 4).tolist()}\n"
            f"    SE {np.round(res.se[n], 4).tolist()} (textbook {np.round(res.se_textbook[n], 4).tolist()})\n"
            f"    error/SE {np.round(z, 2).tolist()}; relative error (Frobenius) {rel:.3f}"
        )
        out["parameters"][n] = dict(
            estimate=res.values[n].tolist(),
            truth=true[n].tolist(),
            se=res.se[n].tolist(),
            se_textbook=res.se_textbook[n].tolist(),
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
    a = parse(sys.argv[1:] if argv is None else argv)
    import jax

    jax.config.update("jax_enable_x64", True)
    import numpy as np

    import armimp_jax as aj
    from armimp_jax.study import atomic_write_json

    t0 = time.perf_counter()
    settings = {k: v for k, v in vars(a).items() if k != "out"}
    if a.must_show:
        atomic_write_json(a.out, dict(settings=settings, must_show=must_show(aj, np, jax, a)))
        return
    rows = [run_case(aj, np, jax, c, t, a) for c, t in a.cases]
    print(f"\ncoverage of 95% intervals, {a.seeds} seeds, {a.seconds:g} s records, peak {a.peak:g} N")
    print(f"{'case':<16}{'group':<17}{'boot':>6}{'textbk':>8}{'spread/SE':>11}{'pred/spread':>13}{'|bias|/sd':>10}")
    for r in rows:
        for g, v in r["groups"].items():
            print(
                f"{r['controller'] + ' ' + format(r['tau_c'], 'g') + ' N m':<16}{g:<17}{v['coverage']:>6.2f}"
                f"{v['coverage_textbook']:>8.2f}{v['spread_over_se']:>11.2f}{v['predicted_over_spread']:>13.2f}"
                f"{v['mean_error_over_spread']:>10.2f}"
            )
        print(
            f"{'':<16}{'all':<17}{r['coverage_all']:>6.2f}   converged {r['converged']}/{r['recordings']}, "
            f"intervals reliable {r['reliable']}/{r['recordings']} (median linearity {r['median_linearity']:.2f} SE), "
            f"{r['mean_time_s']:.1f} s per identify"
        )
        for part in ("reliable", "flagged"):
            if r[f"coverage_{part}"] is not None:
                print(f"{'':<16}{part:<17}{r['coverage_' + part]:>6.2f}")
    elapsed = time.perf_counter() - t0
    print(f"total {elapsed:.0f} s")
    clean = [{k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in r.items()} for r in rows]
    atomic_write_json(a.out, dict(settings=settings, cases=clean, elapsed_s=elapsed))


if __name__ == "__main__":
    main()
