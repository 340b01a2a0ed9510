"""Benchmark: d phi_T / d Mhat for one 50 s trial (paper settings), forward vs reverse mode.

Each (mode, RK4 kernel, checkpoint) runs in its own process: compile time apart, median of
repeats with ``block_until_ready``; peak RSS (``getrusage``, taken before anything else
is built in that process) and XLA's own temporary buffer size. Each process also times
the forward simulation (simulate + estimate + phi_T, default ``"fast"`` kernel),
alternating with its own runs, and reports the paired ratio. The gradients use
``--kernels`` (default: ``"grad"``, the kernel the tuner uses; add ``fast`` to compare) and
``--checkpoints`` (default: ``"substep"``, the tuner's; add ``period`` to compare).

    python sweeps/bench_gradient.py [--seconds 50] [--substeps 100] [--repeats 3]

The script sets XLA's code generation itself (``configure``), so it opts out of the
options (importing ``armimp_jax`` sets none): ``--no-hoist``
and ``--unroll-loops`` then really leave them off.

``--training-batch`` also times one gradient of ``tune_mhat.py``'s default training batch
(16 trials of 16 s at 20 substeps, nperseg 4096) with each checkpoint, on one device and
sharded over every core by ``tune.place_batch`` (theta replicated, as ``tune.tune`` does),
alternating, in one process.

``--jacobian`` instead times forward-mode Jacobians: ``jax.jacfwd`` of the simulated ``x``
and ``fh`` of one trial (IMBIC, friction 2, location 1) with respect to 16 floats (the arm's
12 entries of ``M``, ``B``, ``K`` and ``tau_c``, ``tau_s`` of both joints), against one
forward run and 16 separate forward runs (at 16 nearby parameter vectors), per solver
setting ``METHOD:KERNEL:SUBSTEPS`` (``--jac-settings``), each in its own process: compile
excluded and reported, ``block_until_ready``, the three alternated, median of repeats.

    python sweeps/bench_gradient.py --jacobian [--seconds 10] [--jac-settings rk4:fast:100,gark4:fast:4]
"""

from __future__ import annotations

import argparse
import pathlib

# aj.Numerics.CHECKPOINTS and aj.solvers.RK4.KERNELS, spelled out so that --help needs no JAX (checked in the children)
CHECKPOINTS = ("period", "substep")
MODES = ("primal", "reverse-diagonal", "reverse-full", "forward-diagonal", "forward-full")
KERNELS = ("fast", "grad", "reference")


JAC_SETTINGS = "rk4:fast:100,rk4:grad:100,ark3:fast:20,gark4:fast:4"
JAC_PARAMETERS = 16  # the arm's M, B, K (12) and tau_c, tau_s of both joints (4)


def parser() -> argparse.ArgumentParser:
    """The command line (no JAX: ``--help`` is instant)."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=50.0)
    ap.add_argument("--substeps", type=int, default=100)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--training-batch", action="store_true", help="also time the tuner's batch gradient")
    ap.add_argument("--jacobian", action="store_true", help="instead: forward-mode Jacobians of 16 parameters")
    ap.add_argument("--jac-settings", default=JAC_SETTINGS, help="METHOD:KERNEL:SUBSTEPS,... for --jacobian")
    ap.add_argument("--child", choices=MODES + ("training", "jacobian"))
    ap.add_argument("--child-setting", help=argparse.SUPPRESS)
    ap.add_argument("--child-kernel", choices=KERNELS)
    ap.add_argument("--child-checkpoint", choices=CHECKPOINTS)
    ap.add_argument("--no-hoist", action="store_true", help="without the XLA small-loop option")
    ap.add_argument("--unroll-loops", action="store_true", help="leave LLVM's loop unrolling on (XLA's default)")
    ap.add_argument("--modes", nargs="+", choices=MODES[1:], default=list(MODES[1:]))
    ap.add_argument("--kernels", nargs="+", choices=KERNELS, default=["grad"], help="RK4 kernels of the gradients")
    ap.add_argument(
        "--checkpoints",
        nargs="+",
        choices=CHECKPOINTS,
        default=["substep"],
        help="reverse-mode tapes (Numerics.checkpoint)",
    )
    ap.add_argument("--out", type=pathlib.Path, default=pathlib.Path("results/bench"))
    return ap


if __name__ == "__main__":
    ARGS = parser().parse_args()
    from armimp_bench import gradient

    gradient.main(ARGS, script=__file__)
