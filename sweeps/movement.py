"""A lab's day for a movement: M, and B and K at every knot with 95% intervals (aj.estimate_ensemble).

    python sweeps/movement.py CONFIG.toml --out DIR [--simulate]

CONFIG.toml (docs/movement.md): the reach, knots, controller, perturbation, repetitions, and the lab's recordings
([ensemble] files; none, or --simulate: the reach simulated). Writes movement.csv, movement.json,
stiffness_ellipses.png and impedance_time.png in DIR.
"""

import sys

from armimp_jax.study.runs.cli import Parser, import_kinds, script


@script("movement")
def main(argv=None):
    p = Parser(prog="movement", description=__doc__, kinds=True)
    p.add_argument("config", help="TOML config (see above; the base case: sweeps/configs/movement_base.toml)")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder (created)")
    p.add_argument("--simulate", action="store_true", help="simulate the config's reach even where files are listed")
    a = p.parse_args(argv)
    from armimp_jax.runtime import configure  # after the options: --help answers at once

    configure()  # float64, the devices, XLA:CPU's options
    import_kinds(a.imports, "movement")
    from armimp_jax.study.recording.movement_day import run_day

    run_day(a.config, a.out, simulate=a.simulate)
    return 0


if __name__ == "__main__":
    sys.exit(main())
