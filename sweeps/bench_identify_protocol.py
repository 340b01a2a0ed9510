"""A lab's protocol checked by Monte Carlo (issue 47; armimp_jax.bench.protocol): calibration of
the robot pooled with the human's recording, a robot without a force transducer, repeated
trials and four postures in one identification.

Per case and seed, fresh recordings are drawn and identified in one call, started at the
truth's arm; the share of 95% intervals holding the truth and the SD of the z-scores are
reported per entry. Cases: uncalibrated, calibrated, motor-force, one-trial, four-trials,
four-postures (the module's docstring says what each holds). A run folder (--out) keeps one
checked record per seed and case (a rerun resumes; more seeds extend it) and protocol.json.

    python sweeps/bench_identify_protocol.py --cases calibrated,uncalibrated --seeds 50 --out results/protocol
"""

from __future__ import annotations

import sys

from armimp_jax.study.cli import Parser, fail, parse_names, script

PROG = "bench_identify_protocol"
CASES = ("uncalibrated", "calibrated", "motor-force", "one-trial", "four-trials", "four-postures")


def parse(argv):
    p = Parser(prog=PROG, description=__doc__.split("\n\n")[0])
    p.add_argument("--cases", default=",".join(CASES), help=f"comma list of {', '.join(CASES)} (default all)")
    p.add_argument("--seeds", type=int, default=50, help="recordings per case (default 50)")
    p.add_argument("--draws", type=int, default=64, help="identify's noise draws (default 64)")
    p.add_argument("--out", default="results/protocol", help="run folder (resumed)")
    a = p.parse_args(argv)
    a.cases = parse_names(a.cases, CASES, PROG)
    if a.seeds < 2 or a.draws < 8:
        fail(f"need --seeds >= 2 and --draws >= 8; got {a.seeds} and {a.draws}", PROG)
    return a


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
    from armimp_jax.bench import protocol

    print(_table(protocol.study(a.cases, a.seeds, a.out, draws=a.draws)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
