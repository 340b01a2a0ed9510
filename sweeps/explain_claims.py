"""Why four of the paper's claims are only "partly" reproduced: one controlled experiment each.

    python sweeps/explain_claims.py              # the study of docs/claims_explained.md (about 9 min on 2 cores)
    python sweeps/explain_claims.py --quick      # a smoke run: 6 s records, 1024-sample segments, 2 seeds
    python sweeps/explain_claims.py --out DIR    # the run folder (default results/claims-explained[-quick])

Each experiment changes one assumption of the reproduction and keeps the rest (the paper's
arms, friction levels, gains, perturbation filter and Table 4 Welch settings; seed ``s``
draws its perturbation from ``fold_in(PRNGKey(0), s)`` like ``reproduce_paper.py``, so
seeds 0-2 are the reproduction's trials):

- A, claim (b), coherence below 2 Hz: PD with friction over 10 seeds, the paper's 50 s
  records against 200 s records (4x the segments at Table 4's resolution, or Table 4's
  segment count at 4x the resolution), and a 30x smaller bristle damping sigma1.
- B, claims (b) phase error and (c): PD, location 1, the perturbation's peak force swept
  at friction levels 1 and 2, with instant samples (the reproduction's acquisition) and
  interval means (anti-aliased); how often the joints slide and how often the
  perturbation's joint torque alone exceeds stiction.
- C, claim (c): the Coulomb torque swept between the paper's levels 1 and 2 (stiction
  1.5x), perturbation levels 1 and 3.
- D, claim (d), no friction: the coherence dip near 1.3-1.7 Hz against the Welch segment
  length and the number of segments.
- E, claims (d) and (e): IMBIC's Mhat, its acceleration estimate and the acquisition, on
  the paper's conditions (four locations, three friction levels), judged by the
  reproduction's own rules; and Mhat 0.25, 0.5 and 1.0 I kg (the last also with
  interval means) with 200 s records and 32768-sample segments.

Every trial runs with ``aj.solvers.SWEEP_NUMERICS`` (ARK3, 20 substeps; at friction levels 1 and 2
its phi_T agrees with the paper's RK4 at 100 substeps to about 1e-6, which seeds 0-2 of
experiment B show against the reproduction's report). Writes DIR/claims_explained.md (one
Markdown section, with the wall time) and prints it; DIR also holds the run (``run.json``,
one checked record per trial), so an interrupted study resumes with the same command.
"""

from __future__ import annotations

import pathlib
import sys

from armimp_jax.study.runs.cli import Parser, fail, script

PROG = "explain_claims"


def parse(argv):
    ap = Parser(prog=PROG, description=__doc__)
    ap.add_argument("--quick", action="store_true", help="6 s / 12 s records, 1024 / 4096-sample segments, 2 seeds")
    ap.add_argument("--out", type=pathlib.Path, help="run folder (default results/claims-explained[-quick])")
    ap.add_argument("--batch-size", type=int, default=24, help="trials per vmapped batch (does not change results)")
    ap.add_argument("--only", default="ABCDE", help="experiments to run, e.g. 'BE' (default ABCDE)")
    args = ap.parse_args(argv)
    if args.batch_size < 1:
        fail(f"--batch-size must be >= 1, got {args.batch_size}", PROG)
    bad = set(args.only) - set("ABCDE")
    if bad or not args.only:
        fail(f"--only takes letters of ABCDE, got {args.only!r}", PROG)
    if args.out is None:
        args.out = pathlib.Path("results/claims-explained" + ("-quick" if args.quick else ""))
    return args


@script(PROG)
def main(argv=None) -> int:
    args = parse(argv)
    from armimp_jax.runtime import configure

    configure()
    from armimp_jax.paper import explain
    from armimp_jax.study.runs.console import Console

    console = Console()
    settings = explain.ExplainSettings(quick=args.quick, only=args.only)
    outcome = explain.explain(settings, args.out, batch_size=args.batch_size, console=console, warn=console.warn(PROG))
    path, lines = outcome.finished
    print("\n".join(lines))
    print(f"{len(outcome.computed)} trial(s) run now, {len(outcome.done)} found on disk: {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
