"""identify's efficiency against the Cramér-Rao bound, and its coverage, over repeated recordings
(docs/identification.md, the efficiency table).

Per case (controller, paper arm location, IMBIC's desired stiffness, Coulomb torque with
stiction 1.5 times it, perturbation): force noise 0.05 N, 2^18-count encoders, the person's
force 0.3 N RMS below 2 Hz, one perturbation (key 2024), then per seed a recording under new
noise and ``aj.identify`` of the arm's 12 entries from the truth (the intervals and the
spread are what is measured). Per case and entry: the bound (``aj.crlb``; of the loop
without friction, which is what IMBIC promises to leave; none through stick-slip),
``aj.predict_se``, the estimates' spread, spread / bound, and the share of 95% intervals
that hold the truth. A run folder (``--out``) holds one checked record per recording, saved
as it finishes (a rerun with the same settings resumes), and ``efficiency.json`` (strict
JSON with the settings and the package version). The study is
``armimp_bench.identification.efficiency``.

    python sweeps/bench_identify_efficiency.py --seeds 50 --out results/efficiency
    python sweeps/bench_identify_efficiency.py --statistic welch --out results/efficiency-welch
"""

from __future__ import annotations

import pathlib
import sys
import time

from armimp_jax.study.runs.cli import Parser, fail, script

PROG = "bench_identify_efficiency"
CASES = (  # armimp_bench.identification.CASES's names (spelled out: --help imports no JAX)
    "imbic-a2",
    "imbic-a2-k80",
    "imbic-a4-k80-1Nm",
    "pd-a2",
    "pd-a2-0.3Nm",
    "pd-a2-1Nm",
    "imbic-a2-0.3Nm-tau_c-free",
    "imbic-a4-k80-1Nm-mean",
)
DEFAULT_CASES = CASES[:6]


def parse(argv):
    p = Parser(prog="bench_identify_efficiency", description=__doc__.split("\n\n")[0])
    p.add_argument("--seeds", type=int, default=50, help="recordings per case (default 50)")
    p.add_argument("--seconds", type=float, default=20.0, help="record length [s] (default 20)")
    p.add_argument("--draws", type=int, default=64, help="identify's noise draws (default 64)")
    p.add_argument("--statistic", default="auto", choices=("auto", "efficient", "welch"), help="identify's")
    p.add_argument("--cases", default=",".join(DEFAULT_CASES), help=f"comma list of {', '.join(CASES)}")
    p.add_argument("--out", default="results/identify-efficiency", help="run folder of the results (resumed)")
    p.add_argument("--markdown", action="store_true", help="print the saved results as a Markdown table (no runs)")
    a = p.parse_args(argv)
    a.cases = a.cases.split(",")
    unknown = [c for c in a.cases if c not in CASES]
    if unknown:
        fail(f"--cases: unknown {unknown}; known: {', '.join(CASES)}", p.prog)
    if a.seeds < 3 or a.seconds < 2 or a.draws < 8:
        fail("need --seeds >= 3, --seconds >= 2 and --draws >= 8", p.prog)
    return a


@script(PROG)
def main(argv=None):
    a = parse(sys.argv[1:] if argv is None else argv)
    if a.markdown:
        from armimp_bench.identification import print_markdown
        from armimp_jax.study.runs.results import read_json

        print_markdown(read_json(pathlib.Path(a.out) / "efficiency.json"))
        return 0
    from armimp_jax.runtime import configure

    configure()
    from armimp_bench import identification

    t0 = time.perf_counter()
    cases = identification.efficiency(a, a.out)
    identification.print_table(dict(cases=cases), a)
    print(f"total {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
