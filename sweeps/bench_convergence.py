"""Convergence study: phi_T error and cost per trial, per integration method and substeps.

For every controller (PD, IMBIC), Coulomb torque ``tau_c`` (stiction ``1.5 tau_c``, the
paper's bristle and viscous parameters; 0 is ``tau_c = tau_s = 0``) and paper arm, one trial
is simulated under each setting ``METHOD:SUBSTEPS`` and under the reference setting (by
default ``ark4`` at 4x the finest substeps tested), all with the same seeded perturbation
(paper level 1). The error of a setting is ``|phi_T - phi_T,ref| / phi_T,ref``; the tables
give its maximum over the arms per ``tau_c``, divergences, and the cost per trial.

Cost: the batch of one controller's trials (``simulate_batch`` over every device of
``runtime.configure``), compiled on a one-chunk warm-up (compile time reported apart),
then the full record timed once (``block_until_ready`` via the host copy), amortised per
trial. The reference runs are timed too, but not reported.

    python sweeps/bench_convergence.py [--seconds 50] [--settings rk4:25,ark3:20,...] [--out DIR]
    python sweeps/bench_convergence.py --timing [--batch 24] [--repeats 3]   # cost only

Writes ``DIR/convergence.json`` (every number) and ``DIR/convergence.md`` (the tables).
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import platform
import sys
import time

DEFAULT_TAUS = (0.0, 1e-4, 1e-3, 1e-2, 0.05, 0.2, 1.0, 4.0)
DEFAULT_SETTINGS = "rk4:10,rk4:25,rk4:100,ark3:10,ark3:20,ark3:40,ark4:10,ark4:20,ark4:40"
CHUNK = 5000  # samples per compiled chunk: the warm-up runs one chunk


def parse(argv):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=50.0, help="record length [s] (default 50)")
    ap.add_argument("--taus", type=str, default=",".join(f"{t:g}" for t in DEFAULT_TAUS), help="Coulomb torques [N m]")
    ap.add_argument("--locations", type=int, nargs="+", default=[1, 2, 3, 4], choices=[1, 2, 3, 4])
    ap.add_argument("--controllers", nargs="+", default=["pd", "imbic"], choices=["pd", "imbic"])
    ap.add_argument("--settings", type=str, default=DEFAULT_SETTINGS, help="METHOD:SUBSTEPS,... to assess")
    ap.add_argument("--reference", type=str, help="METHOD:SUBSTEPS (default ark4 at 4x the finest setting)")
    ap.add_argument("--timing", action="store_true", help="instead: cost per trial only (median of --repeats)")
    ap.add_argument("--batch", type=int, default=24, help="--timing: IMBIC trials per batch (default 24)")
    ap.add_argument("--repeats", type=int, default=3, help="--timing: timed runs per setting (default 3)")
    ap.add_argument("--out", type=pathlib.Path, default=pathlib.Path("results/bench"))
    args = ap.parse_args(argv)

    def setting(text):
        method, _, n = text.partition(":")
        if method not in ("rk4", "ark3", "ark4") or not n.isdigit() or int(n) < 1:
            ap.error(f"a setting is METHOD:SUBSTEPS with METHOD rk4, ark3 or ark4 and SUBSTEPS >= 1, got {text!r}")
        return method, int(n)

    args.settings = [setting(s) for s in args.settings.split(",")]
    finest = max(n for _, n in args.settings)
    args.reference = setting(args.reference) if args.reference else ("ark4", 4 * finest)
    try:
        args.taus = [float(t) for t in args.taus.split(",")]
    except ValueError:
        ap.error(f"--taus takes comma-separated numbers, got {args.taus!r}")
    if any(t < 0 for t in args.taus):
        ap.error(f"--taus must be >= 0 N m, got {args.taus}")
    if args.seconds * 1000 < 2 * CHUNK:
        ap.error(f"--seconds must be >= {2 * CHUNK / 1000:g} (two chunks), got {args.seconds}")
    return args


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
        trials.append(aj.make_trial(base.controller, arm=base.arm, friction=aj.LuGre(tau, 1.5 * tau)))
    batch = aj.stack_trials(trials)
    fd = np.broadcast_to(fd1, (args.batch, n, 2))
    settings = args.settings
    compile_s, times = {}, {s: [] for s in settings}
    for method, k in settings:
        t0 = time.perf_counter()
        aj.simulate_batch(batch, fd[:, :CHUNK], numerics=aj.Numerics(substeps=k, method=method), chunk_samples=CHUNK)
        compile_s[(method, k)] = time.perf_counter() - t0
    for _ in range(args.repeats):
        for method, k in settings:
            t0 = time.perf_counter()
            aj.simulate_batch(batch, fd, numerics=aj.Numerics(substeps=k, method=method), chunk_samples=CHUNK)
            times[(method, k)].append((time.perf_counter() - t0) / args.batch)
    rows = [
        dict(
            setting=f"{m}:{k}",
            seconds_per_trial=float(np.median(times[(m, k)])),
            runs=times[(m, k)],
            warmup_with_compile_s=compile_s[(m, k)],
        )
        for m, k in settings
    ]
    lines = [
        f"Cost per {n / 1000:g} s IMBIC trial, batch {args.batch} on {n_devices} device(s), "
        f"median of {args.repeats} (compile excluded)",
        "",
        "| setting | s/trial | warm-up incl. compile [s] |",
        "|---|---|---|",
    ] + [f"| {r['setting']} | {r['seconds_per_trial']:.4f} | {r['warmup_with_compile_s']:.1f} |" for r in rows]
    return dict(rows=rows, batch=args.batch, repeats=args.repeats), "\n".join(lines) + "\n"


def main(argv=None):
    args = parse(argv)
    os.environ["ARMIMP_JAX_XLA_DEFAULTS"] = "0"  # configure() below sets code generation
    from armimp_jax import runtime

    n_devices = runtime.configure()
    import jax
    import numpy as np

    import armimp_jax as aj
    from armimp_jax import paper

    n = int(round(args.seconds * 1000))
    n = -(-n // CHUNK) * CHUNK
    fd1 = np.asarray(aj.perturbation(jax.random.key(0), n, peak=paper.perturbation_peak(1)))
    host = dict(platform=platform.platform(), cpus=os.cpu_count(), devices=n_devices, python=sys.version)
    if args.timing:
        results, table = timing(args, n, fd1, n_devices)
        results["host"] = host
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "convergence_timing.json").write_text(json.dumps(results, indent=1, allow_nan=False))
        (args.out / "convergence_timing.md").write_text(table)
        print(table)
        return
    settings = args.settings + [args.reference]
    results = {"settings": [f"{m}:{k}" for m, k in settings], "reference": "{}:{}".format(*args.reference), "rows": []}
    for ctrl in args.controllers:
        trials, labels = [], []
        for tau in args.taus:
            friction = aj.LuGre(tau, 1.5 * tau)
            for loc in args.locations:
                base = paper.trial(ctrl, 0, loc)
                trials.append(aj.make_trial(base.controller, arm=base.arm, friction=friction))
                labels.append((tau, loc))
        batch = aj.stack_trials(trials)
        fd = np.broadcast_to(fd1, (len(trials), n, 2))
        per_setting = {}
        for method, k in settings:
            numerics = aj.Numerics(substeps=k, method=method)
            t0 = time.perf_counter()
            aj.simulate_batch(batch, fd[:, :CHUNK], numerics=numerics, chunk_samples=CHUNK)
            compile_s = time.perf_counter() - t0
            t0 = time.perf_counter()
            sim = aj.simulate_batch(batch, fd, numerics=numerics, chunk_samples=CHUNK)
            wall = time.perf_counter() - t0
            out = aj.assess_batch(batch, fd, sim)
            per_setting[(method, k)] = out
            print(
                f"{ctrl} {method}:{k}: {wall / len(trials):.4f} s/trial "
                f"(warm-up incl. compile {compile_s:.1f} s), diverged {int(np.sum(out.diverged))}",
                flush=True,
            )
            results["rows"].append(
                dict(
                    controller=ctrl,
                    setting=f"{method}:{k}",
                    seconds_per_trial=wall / len(trials),
                    warmup_with_compile_s=compile_s,
                    trials=[
                        dict(
                            tau_c=tau,
                            location=loc,
                            phi_T=float(out.phi_T[i]) if np.isfinite(out.phi_T[i]) else None,
                            diverged=bool(out.diverged[i]),
                        )
                        for i, (tau, loc) in enumerate(labels)
                    ],
                )
            )
    results["host"] = host
    results["seconds"] = n / 1000
    args.out.mkdir(parents=True, exist_ok=True)
    tables = markdown(results, args.taus)
    (args.out / "convergence.json").write_text(json.dumps(results, indent=1, allow_nan=False))
    (args.out / "convergence.md").write_text(tables)
    print(tables)


def _errors(results):
    """``{(controller, setting): {tau: (max relative error, diverged count)}}`` against the reference."""
    ref = {
        (r["controller"], t["tau_c"], t["location"]): t
        for r in results["rows"]
        if r["setting"] == results["reference"]
        for t in r["trials"]
    }
    out = {}
    for r in results["rows"]:
        if r["setting"] == results["reference"]:
            continue
        cell = out.setdefault((r["controller"], r["setting"]), {})
        for t in r["trials"]:
            rt = ref[(r["controller"], t["tau_c"], t["location"])]
            err, div = cell.get(t["tau_c"], (0.0, 0))
            if t["diverged"] or t["phi_T"] is None or rt["phi_T"] is None or rt["diverged"]:
                cell[t["tau_c"]] = (err, div + 1)
            else:
                cell[t["tau_c"]] = (max(err, abs(t["phi_T"] - rt["phi_T"]) / rt["phi_T"]), div)
    return out


def markdown(results, taus) -> str:
    errors = _errors(results)
    cost = {(r["controller"], r["setting"]): r["seconds_per_trial"] for r in results["rows"]}
    head = "| controller | setting | s/trial | " + " | ".join(f"tau_c={t:g}" for t in taus) + " |"
    lines = [
        f"phi_T relative error against {results['reference']} (max over arms; D: diverged trials), "
        f"{results['seconds']:g} s records, cost per trial amortised over the batch",
        "",
        head,
        "|" + "---|" * (3 + len(taus)),
    ]
    for (ctrl, setting), cells in errors.items():
        row = [ctrl, setting, f"{cost[(ctrl, setting)]:.4f}"]
        for t in taus:
            err, div = cells[t]
            row.append(f"{div}D" if div else f"{err:.1e}")
        lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
