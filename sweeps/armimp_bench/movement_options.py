"""``sweeps/bench_movement.py``'s options, parsed and checked before JAX is set up (``--help`` and
a bad value answer at once)."""

from __future__ import annotations

import sys

from armimp_jax.study.runs.cli import Parser, fail


def setup(argv=None, description: str = ""):
    """The options (``--ensembles``, ``--repetitions``, ``--peak``, ``--windows`` as floats, ``--out``),
    then JAX set up (``runtime.configure``); one line and exit status 2 for a bad value."""
    p = Parser(prog="bench_movement", description=description)
    p.add_argument("--ensembles", type=int, default=50, help="ensembles (default 50)")
    p.add_argument("--repetitions", type=int, default=50, help="reaches per ensemble (default 50)")
    p.add_argument("--peak", type=float, default=2.25, help="perturbation peak [N] per axis (default 2.25)")
    p.add_argument("--windows", default="0.1", help="windows [s] beyond the end knots, comma list (default 0.1)")
    p.add_argument("--out", default="results/movement-coverage", help="run folder (resumed)")
    p.add_argument("--route", choices=("classical", "model"), default="classical", help="the route measured")
    cases = ("imbic", "pd", "pd-designed", "imbic-lugre")  # movement_model.CASES (JAX not yet set up)
    p.add_argument("--case", choices=cases, default="imbic", help="the model route's case")
    p.add_argument("--first", type=int, default=0, help="the first ensemble's seed (default 0)")
    p.add_argument(
        "--check-reaches",
        nargs=2,
        metavar=("PAPER_DIRS", "DESIGNED_DIRS"),
        help="the model route's records (comma lists of run folders, pd and pd-designed): reaches_for "
        "against the spread and the design's ratio, written to --out/reaches_check.json",
    )
    a = p.parse_args(sys.argv[1:] if argv is None else argv)
    try:
        a.windows = [float(w) for w in a.windows.split(",")]
    except ValueError:
        fail(f"--windows takes a comma list of seconds, got {a.windows!r}", p.prog)
    if a.ensembles < 2 or a.repetitions < (23 if a.route == "classical" else 8):
        fail("need --ensembles >= 2, --repetitions >= 23 (five knots; 8 for the model route)", p.prog)
    from armimp_jax.runtime import configure

    configure()
    return a


def coverage(a) -> dict:
    """The measured route's summary (``a.route``): the classical route's or the model route's; with
    ``--check-reaches``, issue 62's two counts from records already on disk."""
    from armimp_bench import movement, movement_model

    if a.check_reaches:
        import pathlib

        from armimp_bench import movement_reaches
        from armimp_jax.study.runs.results import atomic_write_json, stamped

        paper, designed = (d.split(",") for d in a.check_reaches)
        out = stamped(dict(movement_reaches.check(paper, designed), folders=dict(paper=paper, designed=designed)))
        pathlib.Path(a.out).mkdir(parents=True, exist_ok=True)
        atomic_write_json(pathlib.Path(a.out) / "reaches_check.json", out)
        return out

    run = movement_model.model_coverage if a.route == "model" else movement.classical_coverage
    return run(a, a.out)["summary"]
