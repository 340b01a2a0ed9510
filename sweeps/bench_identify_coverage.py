"""Coverage of identify's 95% intervals over repeated noise draws, the classical route's beside
them, and predict_se against the spread of the estimates (docs/identification.md).

For each case (a controller kind at its defaults: ``pd``, ``imbic``, ``admittance``; a
Coulomb torque tau_c of the ``--friction`` law: LuGre with tau_s = 1.5 tau_c, or
CoulombViscous with ``--viscous``; paper arm at location 2; force noise 0.05 N, 2^18-count
encoders, voluntary force 0.3 N RMS below 2 Hz; ``--acquisition``): one perturbation, then
per seed a recording under new noise, ``aj.identify`` of the arm's 12 entries and the free
friction parameters, started at the truth (the intervals are what is tested here;
``--must-show`` tests the descent from afar), and the classical answer of the same
recording (Welch + ``fit_impedance`` with spectral SEs). Reported per case and parameter:
the share of 95% intervals that cover the truth, the estimates' spread over the mean SE,
their mean error over the spread, ``aj.predict_se`` over the spread, and the spread over
``aj.crlb`` (where the loop has a bound). A run folder (``--out``) holds one checked record
per recording, saved as it finishes (a rerun with the same settings resumes where it
stopped; more seeds extend it), and ``coverage.json`` (strict JSON with the settings and
the package version). The study is ``armimp_bench.identification.coverage``.

    python sweeps/bench_identify_coverage.py --seeds 100 --seconds 10 --out results/coverage
    python sweeps/bench_identify_coverage.py --must-show --out must_show.json
    python sweeps/bench_identify_coverage.py --cases admittance:0 --free arm --seconds 20 --peak 2.25 --seeds 50
    python sweeps/bench_identify_coverage.py --must-show --friction coulomb_viscous --cases pd:0.06 \
        --free arm,tau_c,viscous
"""

from __future__ import annotations

import sys
import time

from armimp_jax.study.runs.cli import Parser, fail, parse_cases, script

PROG = "bench_identify_coverage"
ARM = ("arm.mass", "arm.damping", "arm.stiffness")
DEFAULT_CASES = "pd:0.2,pd:1,imbic:0.2,imbic:1"


def parse(argv):
    p = Parser(prog="bench_identify_coverage", description=__doc__.split("\n\n")[0])
    p.add_argument("--seeds", type=int, default=100, help="recordings (noise draws) per case (default 100)")
    p.add_argument("--seconds", type=float, default=10.0, help="record length [s] (default 10; --must-show: 20)")
    p.add_argument("--peak", type=float, default=10.0, help="perturbation peak [N] per axis (default 10)")
    p.add_argument("--draws", type=int, default=64, help="identify's noise draws (default 64)")
    p.add_argument("--voluntary", type=float, default=0.3, help="voluntary force RMS [N] below 2 Hz (default 0.3)")
    p.add_argument("--acquisition", default="instant", choices=("instant", "interval_mean"))
    p.add_argument("--cases", default=DEFAULT_CASES, help="controller:tau_c list [N m] (--must-show: its first)")
    p.add_argument("--friction", default="lugre", choices=("lugre", "coulomb_viscous"), help="the friction law")
    p.add_argument("--viscous", type=float, default=0.0025, help="coulomb_viscous: viscous [N m s/rad]")
    p.add_argument("--free", default="arm,tau_c", help="arm and the law's parameters (comma list; default arm,tau_c)")
    p.add_argument("--out", default="results/identify-coverage", help="run folder (resumed); --must-show: a JSON file")
    p.add_argument("--must-show", action="store_true", help="issue 27's example from a generic start instead")
    a = p.parse_args(argv)
    law = {"lugre": ("tau_c", "tau_s", "sigma0", "sigma1", "sigma2"), "coulomb_viscous": ("tau_c", "viscous")}
    names = {"arm": ARM, **{n: (f"friction.{n}",) for n in law[a.friction]}}
    try:
        a.free = tuple(n for part in a.free.split(",") for n in names[part])
    except KeyError:
        fail(f"--free takes {', '.join(names)} for {a.friction}; got {a.free!r}", p.prog)
    if a.must_show and "--seconds" not in " ".join(argv):
        a.seconds = 20.0
    if a.seeds < 2 or a.seconds < 2 or a.peak <= 0 or a.draws < 8:
        fail("need --seeds >= 2, --seconds >= 2, --peak > 0 and --draws >= 8", p.prog)
    a.cases = parse_cases(a.cases, p.prog, "pd:0.2,imbic:1")
    friction_free = any(n.startswith("friction.") for n in a.free)
    if any(t < 0 or (friction_free and t == 0) for _, t in a.cases):
        fail(f"--cases: tau_c >= 0 (> 0 with friction free); got {a.cases}", p.prog)
    return a


@script(PROG)
def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    a = parse(argv)
    from armimp_jax.runtime import configure

    configure()
    import armimp_jax as aj
    from armimp_bench import identification
    from armimp_jax.study.runs.results import atomic_write_json, stamped

    t0 = time.perf_counter()
    for controller, _ in a.cases:  # a controller kind (one line naming the known ones if not)
        try:
            aj.kinds.controller_kind(controller)
        except ValueError as err:
            fail(f"--cases: {err}", PROG)
    if a.must_show:
        settings = {k: v for k, v in vars(a).items() if k != "out"}
        atomic_write_json(a.out, dict(settings=stamped(settings), must_show=identification.must_show(a)))
        return 0
    cases = identification.coverage(a, a.out)
    print(
        identification.cov.coverage_table(
            cases, seeds=a.seeds, seconds=a.seconds, peak=a.peak, acquisition=a.acquisition
        )
    )
    print(f"total {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
