"""Benchmark: simulation throughput, scaling over devices, the numba baseline, the estimator.

Fixed inputs (seeded perturbations, IMBIC, friction levels and locations cycled), compile
time measured apart, ``block_until_ready``, median of repeats. Entry-point settings as
every script uses them (``runtime.configure``: float64, one XLA device per core, the
small-loop option, 512-bit vectors on AVX-512 hosts; ``--no-wide-vectors`` measures
XLA's default width instead, ``--unroll-loops`` with LLVM's loop unrolling left on).
Prints Markdown tables and writes them (and JSON) under ``--out``.

    python sweeps/bench_simulate.py [--repeats 3] [--quick] [--no-numba] [--no-wide-vectors]

The script sets XLA's code generation itself (``configure``; importing ``armimp_jax`` sets
none), so ``--unroll-loops`` really leaves LLVM's loop unrolling on. What it measures is ``armimp_bench.simulate``.

``--compare-unrolling`` instead times the simulation with and without LLVM's unrolling of
XLA:CPU's loops over the batch (an XLA option, fixed per process): two child processes,
each compiled once, run the same configurations in alternation (so the host's drift hits
both alike) and report whether their outputs agree bit for bit (a digest of each).

``--lanes`` instead times unpadded batches of 1 to two vectors' worth of trials on one
device, the data behind ``aj.batch.padded_batch_size``; ``--large-batch`` times large
batches on one device and ``simulate_batch`` in groups against one group (the data
behind ``aj.batch.MAX_PER_DEVICE``).

``--library-path`` instead (and the default run, as an extra table) times one device
running 24 IMBIC trials (5 s, 100 substeps) the way a library user would,
``aj.simulate_batch(trials, f_delta, numerics=...)`` after ``aj.runtime.configure()`` (the
README's set-up, on one device: ``ARMIMP_JAX_CPU_DEVICES=1``), against the same call after
``runtime.configure(host_devices=1)`` (an entry point's set-up) and in a process that only
switches float64 on (plain XLA: importing ``armimp_jax`` sets no option): three child
processes, compile excluded, alternating run by run, median of repeats.
"""

from __future__ import annotations

import argparse
import os
import pathlib

SETUPS = ("library", "configured", "plain")  # the set-ups --library-path compares, a child each (armimp_bench.paired's)


def parser() -> argparse.ArgumentParser:
    """The command line (built before JAX is imported, so that ``--help`` is instant)."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--substeps", type=int, default=100)
    ap.add_argument("--quick", action="store_true", help="tiny sizes, to check the script runs")
    ap.add_argument("--no-numba", action="store_true", help="skip the numba baseline")
    ap.add_argument("--no-wide-vectors", action="store_true", help="XLA:CPU's default vector width")
    ap.add_argument("--unroll-loops", action="store_true", help="leave LLVM's loop unrolling on (XLA's default)")
    ap.add_argument("--compare-unrolling", action="store_true", help="paired runs with and without loop unrolling")
    ap.add_argument("--lanes", action="store_true", help="unpadded batch sizes around the vector width, one device")
    ap.add_argument("--large-batch", action="store_true", help="large batches: one device, and grouped simulate_batch")
    ap.add_argument(
        "--library-path",
        action="store_true",
        help="simulate_batch as a library user runs it vs configured vs plain XLA",
    )
    ap.add_argument("--seconds", type=float, default=5.0, help="record length of the simulation timings")
    ap.add_argument("--serve", help=argparse.SUPPRESS)
    ap.add_argument("--library-child", choices=SETUPS, help=argparse.SUPPRESS)
    ap.add_argument("--out", type=pathlib.Path, default=pathlib.Path("results/bench"))
    return ap


# parsed before JAX starts: --help needs no JAX, and configure() must run before the backend starts
ARGS = parser().parse_args() if __name__ == "__main__" else None

# The children of --compare-unrolling and --library-path start from the caller's
# environment and flags, not this process's.
CALLER_ENV = dict(os.environ)
CALLER_XLA_FLAGS = CALLER_ENV.get("XLA_FLAGS", "")
SETUP = ARGS.library_child if ARGS is not None else None
from armimp_jax import runtime  # noqa: E402

# configure() must run before JAX starts: hence the options parsed above, before any JAX import.
if SETUP == "plain":
    import jax

    import armimp_jax

    armimp_jax.simulate  # noqa: B018  (loading the package's JAX modules sets no option)
    jax.config.update("jax_enable_x64", True)
    N_DEVICES = jax.device_count()
elif SETUP == "library":
    N_DEVICES = runtime.configure(compilation_cache=False)  # the README's set-up (compile times measured)
elif SETUP == "configured":
    N_DEVICES = runtime.configure(host_devices=1, compilation_cache=False)
else:
    N_DEVICES = runtime.configure(
        vector_width=None if ARGS is not None and ARGS.no_wide_vectors else "auto",
        unroll_loops=ARGS is not None and ARGS.unroll_loops,
        compilation_cache=False,  # compile times are measured
    )

if __name__ == "__main__":
    from armimp_bench import simulate

    simulate.main(ARGS, script=__file__, caller_env=CALLER_ENV, n_devices=N_DEVICES)
