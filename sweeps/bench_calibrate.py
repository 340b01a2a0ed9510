"""The robot's and the force transducer's calibration checked by Monte Carlo (armimp_bench.calibration).

Parts (--parts): coverage (calibrate_robot over --seeds pairs of 20 s robot-alone recordings
under PD, the protocol's truth), force (calibrate_force from five loads over --draws), speed
(two 20 s recordings), arm (the arm identified through the calibration, --variants, a run folder
--out that resumes). Prints Markdown tables and writes --json.

    python sweeps/bench_calibrate.py --parts coverage,force,speed --seeds 50 --json results/calibration.json
    python sweeps/bench_calibrate.py --parts arm --variants calibrated --seeds 10 --out results/calibration-arm
"""

from __future__ import annotations

import json
import pathlib
import sys

from armimp_jax.study.runs.cli import Parser, fail, parse_names, script

PROG = "bench_calibrate"
PARTS = ("coverage", "force", "speed", "arm")
VARIANTS = ("calibrated", "nominal", "true", "motor-force")


def parse(argv):
    p = Parser(prog=PROG, description=__doc__.split("\n\n")[0])
    p.add_argument("--parts", default="coverage,force,speed", help=f"comma list of {', '.join(PARTS)}")
    p.add_argument("--seeds", type=int, default=50, help="calibrations (coverage) or recordings (arm); default 50")
    p.add_argument("--draws", type=int, default=200, help="force calibrations (default 200)")
    p.add_argument("--variants", default="calibrated", help=f"arm: comma list of {', '.join(VARIANTS)}")
    p.add_argument("--out", default="results/calibration-arm", help="arm: run folder (resumed)")
    p.add_argument("--json", default=None, help="write every number to this file")
    a = p.parse_args(argv)
    a.parts, a.variants = parse_names(a.parts, PARTS, PROG), parse_names(a.variants, VARIANTS, PROG)
    if a.seeds < 2 or a.draws < 2:
        fail(f"need --seeds >= 2 and --draws >= 2; got {a.seeds} and {a.draws}", PROG)
    return a


@script(PROG)
def main(argv=None):
    a = parse(sys.argv[1:] if argv is None else argv)
    from armimp_jax.runtime import configure

    configure()
    from armimp_bench import calibration as bc

    out = {}
    if "coverage" in a.parts:
        out["coverage"] = bc.coverage(a.seeds, progress=lambda r: print(f"  seed {r['seed']}: {r['time_s']:.2f} s"))
        summary = out["coverage"]["summary"]
        print(bc.coverage_table(summary), "\n", json.dumps({k: summary[k] for k in ("static_law", "kept", "warned")}))
    if "force" in a.parts:
        out["force"] = bc.force_coverage(a.draws)
        print("force:", json.dumps(out["force"]))
    if "speed" in a.parts:
        out["speed"] = bc.speed()
        print("speed:", json.dumps(out["speed"]))
    if "arm" in a.parts:
        out["arm"] = bc.arm_study(a.variants, a.seeds, a.out)
        print(bc.arm_table(out["arm"]))
    if a.json:
        pathlib.Path(a.json).parent.mkdir(parents=True, exist_ok=True)
        pathlib.Path(a.json).write_text(json.dumps(out, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
