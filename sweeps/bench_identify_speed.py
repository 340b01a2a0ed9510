"""identify's speed in a lab's three cases (issue 47; armimp_bench.identify_speed):

    single   one 20 s PD recording through 0.8 / 1.2 N m of LuGre friction, the arm and both
             Coulomb torques free from a generic start (target: 30 s warm)
    pooled   eight 20 s recordings, two at each paper posture, an arm per posture and the
             torques shared (target: 3 min warm)
    checked  the new user's lab, 20 s: admittance through CoulombViscous(0.05), the self-check runs
             (target: 1.5 times 2.4.0's); three warm calls, their median
    linear   PD without friction, 20 s: nothing is checked (target: no slower than 2.4.0)
    reaches  40 reaches (reaches-lugre: through LuGre, target 2 min warm), on 1 then all devices
    script   a 48 s IMBIC recording at 1 N m through estimate_recording.py --model, run twice
             in fresh processes (target: 60 s on the second run)

Each in-process case calls identify twice (the first compiles) and reports both wall times;
the script case reports both runs' wall times. Writes strict JSON with the settings.

    python sweeps/bench_identify_speed.py --out results/bench-identify-speed/speed.json
    python sweeps/bench_identify_speed.py --cases single,script --out speed.json
"""

from __future__ import annotations

import sys

from armimp_jax.study.runs.cli import Parser, parse_names, script

PROG = "bench_identify_speed"
CASES = ("single", "pooled", "script", "checked", "linear", "reaches", "reaches-lugre")


def parse(argv):
    p = Parser(prog=PROG, description=__doc__.split("\n\n")[0])
    p.add_argument("--cases", default=",".join(CASES), help=f"comma list of {', '.join(CASES)} (default all)")
    p.add_argument("--out", default="results/bench-identify-speed/speed.json", help="the JSON file")
    a = p.parse_args(argv)
    a.cases = parse_names(a.cases, CASES, PROG)
    return a


@script(PROG)
def main(argv=None):
    a = parse(sys.argv[1:] if argv is None else argv)
    from armimp_jax.runtime import configure

    configure()
    from armimp_bench import identify_speed

    results = identify_speed.run(a.cases, a.out)
    for name, r in results.items():
        target = r["target_s"]
        other = "against one device" if "speedup" in r else "a ratio to another version's"
        verdict = other if target is None else ("within" if r["second_s"] <= target else "OVER")
        goal = "" if target is None else f" {target:.0f} s"
        more = f"; on one device {r['one_device_s']:.1f} s, {r['speedup']:.2f} times" if "speedup" in r else ""
        print(f"{name}: first {r['first_s']:.1f} s, second {r['second_s']:.1f} s ({verdict}{goal}){more}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
