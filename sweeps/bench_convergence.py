"""Convergence study: phi_T and estimated K errors and cost per trial, per solver and substeps.

For every controller kind (``--controllers``: PD, IMBIC, admittance, at their defaults),
Coulomb torque ``tau_c`` of the ``--friction`` law (LuGre: stiction ``1.5 tau_c``, the paper's
bristle and viscous parameters, 0 is ``tau_c = tau_s = 0``; ``coulomb_viscous``: the tanh law
with ``--v-s`` and ``--viscous``) and paper arm, one trial
is simulated under each setting ``METHOD:SUBSTEPS`` (``rk4``, ``ark3``, ``ark4``, ``gark4``:
``GradedARK4``) with the same seeded perturbation (paper level 1), and scored: ``phi_T``
(``assess_batch``) and the stiffness ``K`` of ``fit_impedance``. A setting's error is
measured against the same solver at ``--refine`` (default 4) times the substeps, the
convergence criterion of issue 26, or against one common ``--reference`` setting:
``|phi_T - phi_T,ref| / phi_T,ref`` and ``||K - K_ref||_F / ||K_ref||_F``. The tables give
their maximum over the arms per ``tau_c`` and controller, divergences, and a summary per
setting (largest errors, converged: no divergence and both errors <= 1e-4).

Cost: in the accuracy run each setting's batch is compiled on a one-chunk warm-up and the
full record timed once (rough: the batch is not the timing batch). ``--timing`` instead
measures the cost per trial properly: ``--batch`` IMBIC trials cycling through the Coulomb
torques and arms, ``simulate_batch`` over every device of ``runtime.configure``, compile
excluded and reported, ``block_until_ready`` (the host copy), median of ``--repeats`` runs
alternated across settings; the host's load average is recorded with every run.

    python sweeps/bench_convergence.py [--seconds 50] [--settings gark4:4,ark3:20] [--refine 4] [--out DIR]
    python sweeps/bench_convergence.py --reference ark3:160 [--settings ...]   # one common reference
    python sweeps/bench_convergence.py --timing [--batch 24] [--repeats 3]     # cost only
    python sweeps/bench_convergence.py --friction coulomb_viscous --v-s 0.001 --controllers pd imbic admittance

Writes ``DIR/convergence.json`` (every number) and ``DIR/convergence.md`` (the tables), or
``convergence_timing.*`` with ``--timing``.
"""

from __future__ import annotations

import argparse
import pathlib
import sys

from armimp_jax.study.runs.cli import METHODS

DEFAULT_TAUS = (0.0, 1e-4, 1e-3, 1e-2, 0.1, 1.0, 4.0)  # issue 26's Coulomb torques [N m]
DEFAULT_SETTINGS = "rk4:25,rk4:100,ark3:10,ark3:20,ark4:5,ark4:10,gark4:4,gark4:5"
CHUNK = 5000  # samples per compiled chunk: the warm-up runs one chunk
TOLERANCE = 1e-4  # issue 26: converged means both errors at most this, and no divergence


def parse(argv):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=50.0, help="record length [s] (default 50)")
    ap.add_argument("--taus", type=str, default=",".join(f"{t:g}" for t in DEFAULT_TAUS), help="Coulomb torques [N m]")
    ap.add_argument("--locations", type=int, nargs="+", default=[1, 2, 3, 4], choices=[1, 2, 3, 4])
    ap.add_argument("--controllers", nargs="+", default=["pd", "imbic"], help="controller kinds (default pd imbic)")
    ap.add_argument("--friction", default="lugre", choices=("lugre", "coulomb_viscous"), help="the friction law")
    ap.add_argument("--v-s", type=float, default=0.01, help="coulomb_viscous: the tanh's scale [rad/s] (0.01)")
    ap.add_argument("--viscous", type=float, default=0.0025, help="coulomb_viscous: viscous [N m s/rad]")
    ap.add_argument("--settings", type=str, default=DEFAULT_SETTINGS, help="METHOD:SUBSTEPS,... to assess")
    ap.add_argument("--refine", type=int, default=4, help="each setting against itself at this many times the substeps")
    ap.add_argument("--reference", type=str, help="METHOD:SUBSTEPS: one common reference instead of --refine")
    ap.add_argument("--seed", type=int, default=0, help="perturbation seed (default 0)")
    ap.add_argument("--timing", action="store_true", help="instead: cost per trial only (median of --repeats)")
    ap.add_argument("--batch", type=int, default=24, help="--timing: IMBIC trials per batch (default 24)")
    ap.add_argument("--repeats", type=int, default=3, help="--timing: timed runs per setting (default 3)")
    ap.add_argument("--out", type=pathlib.Path, default=pathlib.Path("results/bench"))
    args = ap.parse_args(argv)

    def setting(text):
        method, _, n = text.partition(":")
        if method not in METHODS or not n.isdigit() or int(n) < 1:
            allowed = ", ".join(METHODS)
            ap.error(f"a setting is METHOD:SUBSTEPS with METHOD in {allowed} and SUBSTEPS >= 1, got {text!r}")
        return method, int(n)

    args.settings = [setting(s) for s in args.settings.split(",")]
    args.reference = setting(args.reference) if args.reference else None
    if args.refine < 2:
        ap.error(f"--refine must be >= 2, got {args.refine}")
    try:
        args.taus = [float(t) for t in args.taus.split(",")]
    except ValueError:
        ap.error(f"--taus takes comma-separated numbers, got {args.taus!r}")
    if any(t < 0 for t in args.taus):
        ap.error(f"--taus must be >= 0 N m, got {args.taus}")
    if not (args.v_s > 0 and args.viscous >= 0):
        ap.error(f"--v-s must be > 0 and --viscous >= 0, got {args.v_s} and {args.viscous}")
    if args.seconds * 1000 < 2 * CHUNK:
        ap.error(f"--seconds must be >= {2 * CHUNK / 1000:g} (two chunks), got {args.seconds}")
    return args


def main(argv=None):
    args = parse(argv)
    from armimp_jax import runtime

    n_devices = runtime.configure(compilation_cache=False)  # compile times are measured
    from armimp_bench import convergence

    convergence.main(args, n_devices=n_devices)


if __name__ == "__main__":
    sys.exit(main())
