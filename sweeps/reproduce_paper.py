"""Reproduce the paper end to end: PD and IMBIC sweeps, figures, a results report.

    python sweeps/reproduce_paper.py                 # the paper's settings (50 s, 100 substeps, Table 4)
    python sweeps/reproduce_paper.py --quick         # a smoke run in well under a minute
    python sweeps/reproduce_paper.py --seeds 5       # every condition over 5 perturbation seeds
    python sweeps/reproduce_paper.py --resume DIR    # finish an interrupted run
    python sweeps/reproduce_paper.py --replot DIR    # redraw figures and report from saved results

Writes ``DIR/REPORT.md``, PNG figures, ``results.json`` / ``results.npz`` and one file
pair per finished trial under ``DIR/trials`` (default DIR: results/paper or
results/paper-quick).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import pathlib
import sys
import time

from armimp_jax.runtime import configure


def parse(argv):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="short records, 10 substeps, 1024-sample segments")
    ap.add_argument("--seeds", type=int, default=1, help="perturbation seeds per condition (default 1)")
    ap.add_argument("--base-seed", type=int, default=0)
    ap.add_argument("--seconds", type=float, help="record length [s] (default 50; quick 6)")
    ap.add_argument("--substeps", type=int, help="RK4 substeps per 1 ms (default 100; quick 10)")
    ap.add_argument("--nperseg", type=int, help="Welch segment (default 8192; quick 1024)")
    ap.add_argument("--noverlap", type=int, help="Welch overlap (default 6144; quick 768)")
    ap.add_argument("--mhat", type=float, default=0.25, help="IMBIC gain, times the identity [kg]")
    ap.add_argument("--locations", type=int, nargs="+", default=[1, 2, 3, 4], help="IMBIC arm locations")
    ap.add_argument("--frictions", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--perturbations", type=int, nargs="+", default=[1, 2, 3], help="PD perturbation levels")
    ap.add_argument("--no-ablation", action="store_true", help="skip the interval-mean acquisition sweep")
    ap.add_argument("--max-input-coherence", type=float, help="redraw perturbations until below (paper: 0.4)")
    ap.add_argument("--batch-size", type=int, default=48, help="trials per vmapped batch")
    ap.add_argument("--out", type=pathlib.Path, help="output folder")
    ap.add_argument("--resume", type=pathlib.Path, metavar="DIR", help="continue an interrupted run in DIR")
    ap.add_argument("--replot", type=pathlib.Path, metavar="DIR", help="redraw figures and report from DIR")
    return ap.parse_args(argv)


def check_choices(args):
    for name, values, allowed in (
        ("location", args.locations, (1, 2, 3, 4)),
        ("friction", args.frictions, (0, 1, 2)),
        ("perturbation", args.perturbations, (1, 2, 3)),
    ):
        bad = [v for v in values if v not in allowed]
        if bad:
            raise ValueError(f"unknown {name} level(s) {bad}; allowed: {', '.join(map(str, allowed))}")
    if args.batch_size < 1:
        raise ValueError(f"--batch-size must be >= 1, got {args.batch_size}")


def settings_from(args, repro):
    base = repro.QUICK if args.quick else repro.ReproSettings()
    overrides = {
        k: getattr(args, k) for k in ("seconds", "substeps", "nperseg", "noverlap") if getattr(args, k) is not None
    }
    return dataclasses.replace(
        base,
        seeds=args.seeds,
        base_seed=args.base_seed,
        mhat=args.mhat,
        ablation=not args.no_ablation,
        max_input_coherence=args.max_input_coherence,
        **overrides,
    )


class ProgressBar:
    def __init__(self, stream=sys.stderr):
        self.stream, self.last = stream, 0.0

    def __call__(self, p):
        now = time.monotonic()
        if now - self.last < 0.5 and p["done"] < p["total"]:
            return
        self.last = now
        frac = p["done"] / p["total"] if p["total"] else 1.0
        eta = p["eta_s"]
        eta_s = f"{int(eta // 60)}:{int(eta % 60):02d}" if eta == eta else "?"
        bar = "#" * int(30 * frac) + "." * (30 - int(30 * frac))
        self.stream.write(
            f"\r[{bar}] {100 * frac:5.1f}%  trials {p['trials_done']}/{p['trials_total']}  "
            f"elapsed {p['elapsed_s']:.0f} s  ETA {eta_s}  "
        )
        self.stream.flush()


def finish(repro, plots, report, out, *, complete):
    results, arrays = repro.aggregate(out, complete=complete)
    figures = plots.all_figures(results, arrays, out)
    path = report.write_report(results, out, figures)
    return results, path


def main(argv=None):
    args = parse(argv)
    configure()
    from armimp_jax.paper import plots, report
    from armimp_jax.paper import reproduce as repro
    from armimp_jax.paper.claims import paper_conditions

    if args.replot:
        results, arrays = repro.load_results(args.replot)
        figures = plots.all_figures(results, arrays, args.replot)
        print(f"redrew {len(figures)} figures and {report.write_report(results, args.replot, figures)}")
        return 0
    check_choices(args)
    if args.resume:
        out = args.resume
        saved = json.loads((out / "run.json").read_text())["settings"]
        settings = repro.ReproSettings(**saved)
    else:
        settings = settings_from(args, repro)
        out = args.out or pathlib.Path("results/paper-quick" if args.quick else "results/paper")
    settings.validate()
    repro.prepare_output(out, settings, resume=bool(args.resume))
    conditions = paper_conditions(
        ablation=settings.ablation,
        locations=tuple(args.locations),
        frictions=tuple(args.frictions),
        perturbations=tuple(args.perturbations),
    )
    print(
        f"{len(conditions)} conditions x {settings.seeds} seed(s), {settings.seconds:g} s records, "
        f"{settings.substeps} substeps -> {out}",
        flush=True,
    )
    start = time.perf_counter()
    try:
        repro.run_reproduction(
            settings,
            out,
            conditions=conditions,
            batch_size=args.batch_size,
            chunk_seconds=min(5.0, settings.seconds),
            progress=ProgressBar(),
        )
    except KeyboardInterrupt:
        sys.stderr.write("\ninterrupted: finished trials are saved\n")
        _, path = finish(repro, plots, report, out, complete=False)
        print(f"partial report: {path}\nresume with: python sweeps/reproduce_paper.py --resume {out}")
        return 130
    wall = time.perf_counter() - start
    run = json.loads((out / "run.json").read_text())
    run["wall_s"] = (run.get("wall_s") or 0.0) + wall if args.resume else wall
    (out / "run.json").write_text(json.dumps(run, indent=1))
    results, path = finish(repro, plots, report, out, complete=True)
    sys.stderr.write("\n")
    for c in results["claims"]:
        print(f"  ({c['key']}) {c['verdict']:10s} {c['ours']}")
    print(f"done in {wall:.1f} s: {path}")
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except ValueError as err:
        sys.exit(f"error: {err}")
