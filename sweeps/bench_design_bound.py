"""Check a design on the Cramér-Rao bound by Monte Carlo identification (issue 35).

    python sweeps/bench_design_bound.py DESIGN_DIR --seeds 30 --out FILE [--arms 1,2] [--markdown]

DESIGN_DIR is what design_experiment.py wrote (design.json with its config and the designed
controller, perturbation.csv). Per arm of the design's robust set: SEEDS recordings of the
designed experiment under new noise (keys 70000 + seed) at the design's record length, each
identified from the truth (the arm's 12 entries, statistic "auto", 32 draws). It reports per
diagonal entry the bound, the spread, spread / bound and the coverage of the 95% intervals,
and the largest achieved relative spread over the targets against the bound's: the minutes
the design promises follow from the bound by its one-over-square-root law, so this ratio,
squared, is how far the Monte Carlo minutes are from the promised ones. Resumable (each
recording is saved as it finishes); --arms and --first split the work over processes (one
--out each), and --merge A.json B.json ... --out ALL.json combines them.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from _cli import Parser, fail, resumable, run_seeds, spread_and_hits  # noqa: E402

PROG = "bench_design_bound"
ARM = ("arm.mass", "arm.damping", "arm.stiffness")


def parse(argv):
    p = Parser(prog=PROG, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("design", type=pathlib.Path, help="the folder design_experiment.py wrote")
    p.add_argument("--seeds", type=int, default=30, help="recordings per arm (default 30)")
    p.add_argument("--first", type=int, default=0, help="the first seed (default 0): processes share an arm's seeds")
    p.add_argument(
        "--merge", nargs="+", type=pathlib.Path, metavar="FILE", help="combine these runs into --out (no runs)"
    )
    p.add_argument("--arms", default=None, help="comma-separated indices into the design's arms, from 1 (default all)")
    p.add_argument("--out", required=True, help="results JSON (resumed if it exists)")
    p.add_argument("--markdown", action="store_true", help="print the saved results as a Markdown table (no runs)")
    a = p.parse_args(argv)
    if a.first < 0:
        p.error(f"--first must be >= 0, got {a.first}")
    if a.seeds < 2 and a.merge is None:
        p.error(f"--seeds must be >= 2 (a spread), got {a.seeds}")
    return a


def designed_trials(design_dir: pathlib.Path):
    """``(doc, trials, f)``: design.json, the robust set's trials with the designed controller, and
    the perturbation ``(N, 2)`` [N]."""
    import numpy as np

    from armimp_jax.study import design_experiment as dx

    doc = json.loads((design_dir / "design.json").read_text())
    if doc.get("method") != "bound":
        fail(f"{design_dir}/design.json is not a design on the bound (method {doc.get('method')!r})", PROG)
    config = doc["settings"]["config"]
    config["controller"].update({k: v for k, v in doc["controller"].items() if k != "type"})
    trials = dx.build_design(config, where=str(design_dir))[0]
    f = np.loadtxt(design_dir / "perturbation.csv", delimiter=",", skiprows=1)
    return doc, trials, f


def one_seed(aj, np, jax, trial, f, seed):
    rec = jax.jit(aj.simulate, static_argnames="numerics")(
        trial, f, key=jax.random.key(70_000 + seed), numerics=aj.IDENTIFY_NUMERICS
    )
    if bool(rec.diverged):
        return dict(seed=seed, diverged=True)
    res = aj.identify(trial, f, rec.x, rec.fh, free=ARM, key=jax.random.key(seed), draws=32)
    return dict(
        seed=seed,
        diverged=False,
        converged=res.converged,
        statistic=res.statistic,
        time_s=res.time_s,
        values={n: np.asarray(v).tolist() for n, v in res.values.items()},
        se={n: np.asarray(v).tolist() for n, v in res.se.items()},
    )


def summarise(np, rows, trial, row_doc, targets):
    ok = [r for r in rows if not r["diverged"] and r["converged"]]
    rel_spread, rel_bound, out = [], [], dict(seeds=len(rows), converged=len(ok), entries={})
    se_bound = dict(zip([f"{n}[{i},{j}]" for n in ARM for i in range(2) for j in range(2)], row_doc["se_after"]))
    hits = []
    for n in ARM:
        true = np.asarray(getattr(trial.arm, n.split(".")[1]))
        _, _, spread, hit = spread_and_hits(ok, n, true)
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


def merge(np, a, doc, trials, states):
    """One state of several runs' recordings (each seed once), the summaries recomputed."""
    from armimp_jax.study import atomic_write_json

    designs = {st["settings"]["design_time"] for st in states}
    if len(designs) != 1:
        fail("--merge: the runs are of different designs (their design times differ)", PROG)
    robust = doc["settings"]["config"]["design"]["robust"] or [0]
    merged = dict(settings=dict(states[0]["settings"], merged=[str(m) for m in a.merge]), arms={})
    for k, loc in enumerate(robust):
        name = f"arm at location {loc}"
        rows = {r["recording"]: r for st in states for r in st["arms"].get(name, {}).get("seeds", [])}
        if len(rows) < 2:
            continue
        seeds = [rows[s] for s in sorted(rows)]
        merged["arms"][name] = dict(
            seeds=seeds, summary=summarise(np, seeds, trials[k], doc["trials"][k], doc["targets"])
        )
    atomic_write_json(pathlib.Path(a.out), merged)
    print_markdown(merged)


def main(argv=None):
    a = parse(sys.argv[1:] if argv is None else argv)
    import jax

    jax.config.update("jax_enable_x64", True)
    import numpy as np

    import armimp_jax as aj
    from armimp_jax.study import atomic_write_json, read_json

    if a.markdown:
        print_markdown(read_json(pathlib.Path(a.out)))
        return
    doc, trials, f = designed_trials(a.design)
    if a.merge:
        return merge(np, a, doc, trials, [read_json(m) for m in a.merge])
    robust = doc["settings"]["config"]["design"]["robust"] or [0]
    arms = range(1, len(trials) + 1) if a.arms is None else [int(k) for k in a.arms.split(",")]
    bad = [k for k in arms if not 1 <= k <= len(trials)]
    if bad:
        fail(f"--arms {bad[0]} is outside the design's 1..{len(trials)}", PROG)
    settings = dict(design=str(a.design), design_time=doc["time_s"], seeds=a.seeds, first=a.first)
    path = pathlib.Path(a.out)
    state = resumable(path, settings, PROG, arms={})
    for k in arms:
        name = f"arm at location {robust[k - 1]}"
        case = run_seeds(
            state,
            "arms",
            name,
            a.seeds,
            # run_seeds counts 0.., the recording's seed is first + that
            lambda i: dict(one_seed(aj, np, jax, trials[k - 1], f, a.first + i), seed=i, recording=a.first + i),  # noqa: B023
            path,
            report=lambda seed, row: f"  {name} seed {seed}: {row['time_s']:.1f} s, converged {row['converged']}",  # noqa: B023
        )
        case["summary"] = summarise(np, case["seeds"], trials[k - 1], doc["trials"][k - 1], doc["targets"])
        atomic_write_json(path, state)
    print_markdown(state)


if __name__ == "__main__":
    main()
