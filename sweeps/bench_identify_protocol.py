"""A lab's protocol checked by Monte Carlo (issue 47; armimp_bench.protocol): calibration of
the robot pooled with the human's recording, a robot without a force transducer, repeated
trials and four postures in one identification.

Per case and seed, fresh recordings are drawn and identified in one call, started at the
truth's arm; the share of 95% intervals holding the truth and the SD of the z-scores are
reported per entry. Cases: uncalibrated, calibrated, motor-force, one-trial, four-trials,
four-postures (the module's docstring says what each holds). A run folder (--out) keeps one
checked record per seed and case (a rerun resumes; more seeds extend it) and protocol.json.

    python sweeps/bench_identify_protocol.py --cases calibrated,uncalibrated --seeds 50 --out results/protocol

The sensitivity case (named only, in a folder of its own) checks robot_sensitivity's predicted
bias for link inertias 10% off against the paired move of identify on one arm of a design
(--design, a folder design_experiment.py wrote; --design-arm, from 0):

    python sweeps/bench_identify_protocol.py --cases sensitivity --design results/design-imbic --seeds 20 \
        --out results/protocol/sensitivity
"""

from __future__ import annotations

import pathlib
import sys

from armimp_jax.study.runs.cli import Parser, fail, parse_names, script

PROG = "bench_identify_protocol"
CASES = ("uncalibrated", "calibrated", "motor-force", "one-trial", "four-trials", "four-postures")
NAMED_ONLY = ("sensitivity",)


def parse(argv):
    p = Parser(prog=PROG, description=__doc__.split("\n\n")[0])
    names = ", ".join(CASES + NAMED_ONLY)
    p.add_argument("--cases", default=",".join(CASES), help=f"comma list of {names} (default all but sensitivity)")
    p.add_argument("--seeds", type=int, default=50, help="recordings per case (default 50)")
    p.add_argument("--draws", type=int, default=64, help="identify's noise draws (default 64)")
    p.add_argument("--out", default="results/protocol", help="run folder (resumed)")
    p.add_argument("--design", default="results/design-imbic", help="the sensitivity case's design folder")
    p.add_argument("--design-arm", type=int, default=0, help="the sensitivity case's arm of the design (from 0)")
    a = p.parse_args(argv)
    a.cases = parse_names(a.cases, CASES + NAMED_ONLY, PROG)
    if a.seeds < 2 or a.draws < 8:
        fail(f"need --seeds >= 2 and --draws >= 8; got {a.seeds} and {a.draws}", PROG)
    if "sensitivity" in a.cases:
        found = [pathlib.Path(a.design, n).is_file() for n in ("design.json", "perturbation.npz")]
        if not all(found):
            fail(f"--design {a.design} holds no design.json and perturbation.npz: run design_experiment.py first", PROG)
        if a.design_arm < 0:
            fail(f"--design-arm must be >= 0, got {a.design_arm}", PROG)
    return a


def _paired(case: dict) -> str:
    """The sensitivity case: measured against predicted, per arm diagonal."""
    pair = case["paired"]
    lines = [
        f"sensitivity: link inertias 10% off, {pair['both_converged']}/{pair['recordings']} recordings fitted twice",
        "| arm entry | measured move | its SE | predicted | predicted [SE of the entry] | predicted / measured |",
        "|---|---|---|---|---|---|",
    ]
    for label, e in pair["entries"].items():
        if label.endswith(("[0,0]", "[1,1]")):
            ratio = "-" if e["ratio"] is None else f"{e['ratio']:.3f}"
            lines.append(
                f"| {label} | {e['measured']:+.4g} | {e['measured_se']:.2g} | {e['predicted']:+.4g} | "
                f"{e['in_se']:+.2f} | {ratio} |"
            )
    return "\n".join(lines)


def _table(cases: dict) -> str:
    head = "| case | converged | arm coverage | robot coverage | warned | mean time [s] |"
    lines = [head, "|---|---|---|---|---|---|"]
    for name, c in cases.items():
        s = c["summary"]
        cells = [s.get("coverage_arm"), s.get("coverage_other"), s.get("warned"), s.get("mean_time_s")]
        text = ["-" if v is None else f"{v:.3f}" for v in cells]
        lines.append(f"| {name} | {s['converged']}/{s['recordings']} | " + " | ".join(text) + " |")
    return "\n".join(lines)


@script(PROG)
def main(argv=None):
    a = parse(sys.argv[1:] if argv is None else argv)
    from armimp_jax.runtime import configure

    configure()
    from armimp_bench import protocol

    cases = protocol.study(a.cases, a.seeds, a.out, draws=a.draws, design=a.design, design_arm=a.design_arm)
    print(_table(cases))
    if "sensitivity" in cases and "paired" in cases["sensitivity"]:
        print(_paired(cases["sensitivity"]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
