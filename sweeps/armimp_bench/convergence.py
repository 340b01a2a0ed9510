"""What ``sweeps/bench_convergence.py`` measures: each integrator setting's error against a
refined (or common) reference over Coulomb torques, controllers and arms, and its cost per
trial (``--timing``); the script's docstring says what the tables hold.
"""

from __future__ import annotations

import functools
import json
import os
import platform
import statistics
import sys
import time

from armimp_jax.study.runs.cli import solver

DEFAULT_TAUS = (0.0, 1e-4, 1e-3, 1e-2, 0.1, 1.0, 4.0)  # issue 26's Coulomb torques [N m]
DEFAULT_SETTINGS = "rk4:25,rk4:100,ark3:10,ark3:20,ark4:5,ark4:10,gark4:4,gark4:5"
CHUNK = 5000  # samples per compiled chunk: the warm-up runs one chunk
TOLERANCE = 1e-4  # issue 26: converged means both errors at most this, and no divergence


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

    return aj.make_trial(aj.kinds.controller_kind(ctrl)(), arm=presets.arm(loc), friction=aj.NO_FRICTION)


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
    batch = aj.batch.stack_trials(trials)
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
    out = aj.batch.assess_batch(batch, fd, sim)
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


def main(args, *, n_devices: int):
    """The convergence study (or ``--timing``) of ``args`` (``bench_convergence.py``'s), on
    ``n_devices`` devices; tables and JSON under ``args.out``."""
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
            aj.kinds.controller_kind(ctrl)
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
        batch = aj.batch.stack_trials(trials)
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
