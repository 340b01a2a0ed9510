"""Convergence study: phi_T and estimated K errors and cost per trial, per solver and substeps.

For every controller kind (``--controllers``: PD, IMBIC, admittance, at their defaults),
Coulomb torque ``tau_c`` of the ``--friction`` law (LuGre: stiction ``1.5 tau_c``, the paper's
bristle and viscous parameters, 0 is ``tau_c = tau_s = 0``; ``coulomb_viscous``: the tanh law
with ``--v-s`` and ``--viscous``) and paper arm, one trial
is simulated under each setting ``METHOD:SUBSTEPS`` (``rk4``, ``ark3``, ``ark4``, ``gark4``:
``GradedARK4``) with the same seeded perturbation (paper level 1), and scored: ``phi_T``
(``assess_batch``) and the stiffness ``K`` of ``fit_impedance``. A setting's error is
measured against the same solver at ``--refine`` (default 4) times the substeps, the
convergence criterion of issue 26, or against one common ``--reference`` setting:
``|phi_T - phi_T,ref| / phi_T,ref`` and ``||K - K_ref||_F / ||K_ref||_F``. The tables give
their maximum over the arms per ``tau_c`` and controller, divergences, and a summary per
setting (largest errors, converged: no divergence and both errors <= 1e-4).

Cost: in the accuracy run each setting's batch is compiled on a one-chunk warm-up and the
full record timed once (rough: the batch is not the timing batch). ``--timing`` instead
measures the cost per trial properly: ``--batch`` IMBIC trials cycling through the Coulomb
torques and arms, ``simulate_batch`` over every device of ``runtime.configure``, compile
excluded and reported, ``block_until_ready`` (the host copy), median of ``--repeats`` runs
alternated across settings; the host's load average is recorded with every run.

    python sweeps/bench_convergence.py [--seconds 50] [--settings gark4:4,ark3:20] [--refine 4] [--out DIR]
    python sweeps/bench_convergence.py --reference ark3:160 [--settings ...]   # one common reference
    python sweeps/bench_convergence.py --timing [--batch 24] [--repeats 3]     # cost only
    python sweeps/bench_convergence.py --friction coulomb_viscous --v-s 0.001 --controllers pd imbic admittance

Writes ``DIR/convergence.json`` (every number) and ``DIR/convergence.md`` (the tables), or
``convergence_timing.*`` with ``--timing``.
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import pathlib
import platform
import statistics
import sys
import time

from _cli import METHODS, solver

DEFAULT_TAUS = (0.0, 1e-4, 1e-3, 1e-2, 0.1, 1.0, 4.0)  # issue 26's Coulomb torques [N m]
DEFAULT_SETTINGS = "rk4:25,rk4:100,ark3:10,ark3:20,ark4:5,ark4:10,gark4:4,gark4:5"
CHUNK = 5000  # samples per compiled chunk: the warm-up runs one chunk
TOLERANCE = 1e-4  # issue 26: converged means both errors at most this, and no divergence


def parse(argv):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=50.0, help="record length [s] (default 50)")
    ap.add_argument("--taus", type=str, default=",".join(f"{t:g}" for t in DEFAULT_TAUS), help="Coulomb torques [N m]")
    ap.add_argument("--locations", type=int, nargs="+", default=[1, 2, 3, 4], choices=[1, 2, 3, 4])
    ap.add_argument("--controllers", nargs="+", default=["pd", "imbic"], help="controller kinds (default pd imbic)")
    ap.add_argument("--friction", default="lugre", choices=("lugre", "coulomb_viscous"), help="the friction law")
    ap.add_argument("--v-s", type=float, default=0.01, help="coulomb_viscous: the tanh's scale [rad/s] (0.01)")
    ap.add_argument("--viscous", type=float, default=0.0025, help="coulomb_viscous: viscous [N m s/rad]")
    ap.add_argument("--settings", type=str, default=DEFAULT_SETTINGS, help="METHOD:SUBSTEPS,... to assess")
    ap.add_argument("--refine", type=int, default=4, help="each setting against itself at this many times the substeps")
    ap.add_argument("--reference", type=str, help="METHOD:SUBSTEPS: one common reference instead of --refine")
    ap.add_argument("--seed", type=int, default=0, help="perturbation seed (default 0)")
    ap.add_argument("--timing", action="store_true", help="instead: cost per trial only (median of --repeats)")
    ap.add_argument("--batch", type=int, default=24, help="--timing: IMBIC trials per batch (default 24)")
    ap.add_argument("--repeats", type=int, default=3, help="--timing: timed runs per setting (default 3)")
    ap.add_argument("--out", type=pathlib.Path, default=pathlib.Path("results/bench"))
    args = ap.parse_args(argv)

    def setting(text):
        method, _, n = text.partition(":")
        if method not in METHODS or not n.isdigit() or int(n) < 1:
            allowed = ", ".join(METHODS)
            ap.error(f"a setting is METHOD:SUBSTEPS with METHOD in {allowed} and SUBSTEPS >= 1, got {text!r}")
        return method, int(n)

    args.settings = [setting(s) for s in args.settings.split(",")]
    args.reference = setting(args.reference) if args.reference else None
    if args.refine < 2:
        ap.error(f"--refine must be >= 2, got {args.refine}")
    try:
        args.taus = [float(t) for t in args.taus.split(",")]
    except ValueError:
        ap.error(f"--taus takes comma-separated numbers, got {args.taus!r}")
    if any(t < 0 for t in args.taus):
        ap.error(f"--taus must be >= 0 N m, got {args.taus}")
    if not (args.v_s > 0 and args.viscous >= 0):
        ap.error(f"--v-s must be > 0 and --viscous >= 0, got {args.v_s} and {args.viscous}")
    if args.seconds * 1000 < 2 * CHUNK:
        ap.error(f"--seconds must be >= {2 * CHUNK / 1000:g} (two chunks), got {args.seconds}")
    return args


def numerics(method, substeps):
    """The ``Numerics`` of a ``METHOD:SUBSTEPS`` setting (the solver's default kernel)."""
    import armimp_jax as aj

    return aj.Numerics(solver=solver(method), substeps=substeps)


def friction(aj, args, tau):
    """The ``--friction`` law at Coulomb torque ``tau`` [N m]."""
    if args.friction == "lugre":
        return aj.LuGre(tau, 1.5 * tau)
    return aj.CoulombViscous(tau, viscous=args.viscous, v_s=args.v_s)


def base_trial(aj, ctrl, loc):
    """A frictionless trial of controller kind ``ctrl`` (its defaults) at paper arm ``loc``."""
    from armimp_jax import presets

    return aj.make_trial(aj.controller_kind(ctrl)(), arm=presets.arm(loc), friction=aj.NO_FRICTION)


def label(setting):
    return "{}:{}".format(*setting)


def timing(args, n, fd1, n_devices):
    """Cost per trial of each setting: ``args.batch`` IMBIC trials cycling through the
    Coulomb torques and arms, compile excluded, median of ``args.repeats`` runs, settings
    alternated run by run so the host's drift hits all alike."""
    import numpy as np

    import armimp_jax as aj
    from armimp_jax import paper

    points = [(tau, loc) for tau in args.taus for loc in args.locations]
    trials = []
    for i in range(args.batch):
        tau, loc = points[i % len(points)]
        base = paper.trial("imbic", 0, loc)
        trials.append(aj.make_trial(base.controller, arm=base.arm, friction=friction(aj, args, tau)))
    batch = aj.stack_trials(trials)
    fd = np.broadcast_to(fd1, (args.batch, n, 2))
    settings = args.settings
    compile_s, times, loads = {}, {s: [] for s in settings}, {s: [] for s in settings}
    for s in settings:
        t0 = time.perf_counter()
        aj.simulate_batch(batch, fd[:, :CHUNK], numerics=numerics(*s), chunk_samples=CHUNK)
        compile_s[s] = time.perf_counter() - t0
    for _ in range(args.repeats):
        for s in settings:
            loads[s].append(os.getloadavg()[0])
            t0 = time.perf_counter()
            aj.simulate_batch(batch, fd, numerics=numerics(*s), chunk_samples=CHUNK)
            times[s].append((time.perf_counter() - t0) / args.batch)
    rows = [
        dict(
            setting=label(s),
            seconds_per_trial=statistics.median(times[s]),
            runs=times[s],
            load_average=loads[s],
            warmup_with_compile_s=compile_s[s],
        )
        for s in settings
    ]
    lines = [
        f"Cost per {n / 1000:g} s IMBIC trial, batch {args.batch} on {n_devices} device(s), "
        f"median of {args.repeats} (compile excluded); load average {min(min(v) for v in loads.values()):.1f}-"
        f"{max(max(v) for v in loads.values()):.1f}",
        "",
        "| setting | s/trial | runs [s/trial] | warm-up incl. compile [s] |",
        "|---|---|---|---|",
    ] + [
        f"| {r['setting']} | {r['seconds_per_trial']:.4f} | {', '.join(f'{t:.4f}' for t in r['runs'])} | "
        f"{r['warmup_with_compile_s']:.1f} |"
        for r in rows
    ]
    return dict(rows=rows, batch=args.batch, repeats=args.repeats), "\n".join(lines) + "\n"


def run_setting(batch, fd, setting, labels):
    """Simulate, assess and fit one controller's batch under ``setting``: a result row."""
    import jax
    import numpy as np

    import armimp_jax as aj

    num = numerics(*setting)
    t0 = time.perf_counter()
    aj.simulate_batch(batch, fd[:, :CHUNK], numerics=num, chunk_samples=CHUNK)
    compile_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    sim = aj.simulate_batch(batch, fd, numerics=num, chunk_samples=CHUNK)
    wall = time.perf_counter() - t0
    out = aj.assess_batch(batch, fd, sim)
    fit = functools.partial(aj.fit_impedance, acquisition="plain", se="residual")  # as docs/performance.md
    stiffness = np.asarray(jax.jit(jax.vmap(lambda e: fit(e).stiffness))(out.estimate))
    trials = []
    for i, (tau, loc) in enumerate(labels):
        sound = bool(np.isfinite(out.phi_T[i]) and np.all(np.isfinite(stiffness[i])) and not out.diverged[i])
        trials.append(
            dict(
                tau_c=tau,
                location=loc,
                phi_T=float(out.phi_T[i]) if sound else None,
                K=stiffness[i].tolist() if sound else None,
                diverged=bool(out.diverged[i]),
            )
        )
    return dict(
        setting=label(setting),
        seconds_per_trial=wall / len(labels),
        warmup_with_compile_s=compile_s,
        load_average=os.getloadavg()[0],
        trials=trials,
    )


def main(argv=None):
    args = parse(argv)
    os.environ["ARMIMP_JAX_XLA_DEFAULTS"] = "0"  # configure() below sets code generation
    from armimp_jax import runtime

    n_devices = runtime.configure(compilation_cache=False)  # compile times are measured
    import jax
    import numpy as np

    import armimp_jax as aj
    from armimp_jax import paper

    n = int(round(args.seconds * 1000))
    n = -(-n // CHUNK) * CHUNK
    fd1 = np.asarray(aj.perturbation(jax.random.key(args.seed), n, peak=paper.perturbation_peak(1)))
    host = dict(platform=platform.platform(), cpus=os.cpu_count(), devices=n_devices, python=sys.version)
    args.out.mkdir(parents=True, exist_ok=True)
    if args.timing:
        results, table = timing(args, n, fd1, n_devices)
        results["host"] = host
        (args.out / "convergence_timing.json").write_text(json.dumps(results, indent=1, allow_nan=False))
        (args.out / "convergence_timing.md").write_text(table)
        print(table)
        return
    if args.reference:
        references = {s: args.reference for s in args.settings}
    else:
        references = {(m, k): (m, args.refine * k) for m, k in args.settings}
    runs = list(dict.fromkeys(list(args.settings) + list(references.values())))
    for ctrl in args.controllers:
        try:
            aj.controller_kind(ctrl)
        except ValueError as err:
            raise SystemExit(f"bench_convergence: error: --controllers: {err}") from None
    results = dict(
        friction=dict(law=args.friction, v_s=args.v_s, viscous=args.viscous),
        settings=[label(s) for s in args.settings],
        references={label(s): label(r) for s, r in references.items()},
        seed=args.seed,
        seconds=n / 1000,
        rows=[],
    )
    for ctrl in args.controllers:
        trials, labels = [], []
        for tau in args.taus:
            for loc in args.locations:
                base = base_trial(aj, ctrl, loc)
                trials.append(aj.make_trial(base.controller, arm=base.arm, friction=friction(aj, args, tau)))
                labels.append((tau, loc))
        batch = aj.stack_trials(trials)
        fd = np.broadcast_to(fd1, (len(trials), n, 2))
        for s in runs:
            row = dict(controller=ctrl, **run_setting(batch, fd, s, labels))
            results["rows"].append(row)
            diverged = sum(t["diverged"] for t in row["trials"])
            print(
                f"{ctrl} {row['setting']}: {row['seconds_per_trial']:.4f} s/trial (warm-up incl. compile "
                f"{row['warmup_with_compile_s']:.1f} s, load {row['load_average']:.1f}), diverged {diverged}",
                flush=True,
            )
    results["host"] = host
    tables = markdown(results, args.taus)
    (args.out / "convergence.json").write_text(json.dumps(results, indent=1, allow_nan=False))
    (args.out / "convergence.md").write_text(tables)
    print(tables)


def errors(results):
    """``{(controller, setting): {tau: (phi_T error, K error, diverged count)}}``, each error the
    largest over the arms against the setting's reference."""
    import numpy as np

    by = {
        (r["controller"], r["setting"]): {(t["tau_c"], t["location"]): t for t in r["trials"]} for r in results["rows"]
    }
    out = {}
    for (ctrl, setting), trials in by.items():
        if setting not in results["settings"]:
            continue
        ref = by[(ctrl, results["references"][setting])]
        cell = out.setdefault((ctrl, setting), {})
        for key, t in trials.items():
            rt = ref[key]
            phi, k, div = cell.get(key[0], (0.0, 0.0, 0))
            if t["phi_T"] is None or rt["phi_T"] is None:
                cell[key[0]] = (phi, k, div + 1)
                continue
            phi = max(phi, abs(t["phi_T"] - rt["phi_T"]) / rt["phi_T"])
            kt, kr = np.asarray(t["K"]), np.asarray(rt["K"])
            k = max(k, float(np.linalg.norm(kt - kr) / np.linalg.norm(kr)))
            cell[key[0]] = (phi, k, div)
    return out


def markdown(results, taus) -> str:
    errs = errors(results)
    cost = {(r["controller"], r["setting"]): r["seconds_per_trial"] for r in results["rows"]}
    refs = sorted(set(results["references"].values()))
    against = (
        f"against {refs[0]}"
        if len(refs) == 1 and len(results["settings"]) > 1
        else "against the same solver at the refined substeps"
    )
    head = "| controller | setting | " + " | ".join(f"tau_c={t:g}" for t in taus) + " |"
    rule = "|" + "---|" * (2 + len(taus))
    law = results.get("friction", dict(law="lugre"))
    what = "LuGre, tau_s = 1.5 tau_c" if law["law"] == "lugre" else f"CoulombViscous, v_s {law['v_s']:g} rad/s, "
    what += "" if law["law"] == "lugre" else f"viscous {law['viscous']:g} N m s/rad"
    lines = [f"Friction: {what}.", ""]
    lines += [f"Errors {against} (max over arms; D: diverged trials), {results['seconds']:g} s records, seed "]
    lines[-1] += f"{results['seed']}; references: " + ", ".join(f"{s} -> {r}" for s, r in results["references"].items())
    for title, index in (("phi_T relative error", 0), ("K relative error (Frobenius)", 1)):
        lines += ["", f"{title}:", "", head, rule]
        for (ctrl, setting), cells in errs.items():
            row = [ctrl, setting]
            for t in taus:
                e = cells[t]
                row.append(f"{e[2]}D" if e[2] else f"{e[index]:.1e}")
            lines.append("| " + " | ".join(row) + " |")
    lines += [
        "",
        f"Summary (converged: no divergence and both errors <= {TOLERANCE:g}; s/trial from the accuracy run, rough):",
        "",
        "| setting | largest phi_T error | largest K error | diverged | converged | s/trial (PD, IMBIC) |",
        "|---|---|---|---|---|---|",
    ]
    for setting in results["settings"]:
        cells = [c for (ctrl, s), cs in errs.items() if s == setting for c in cs.values()]
        phi, k, div = max(c[0] for c in cells), max(c[1] for c in cells), sum(c[2] for c in cells)
        ok = "yes" if div == 0 and max(phi, k) <= TOLERANCE else "no"
        costs = ", ".join(f"{cost[(c, setting)]:.3f}" for c in dict.fromkeys(ctrl for ctrl, s in errs if s == setting))
        lines.append(f"| {setting} | {phi:.1e} | {k:.1e} | {div} | {ok} | {costs} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
