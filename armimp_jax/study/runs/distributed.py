"""Many hosts: the command-line options and set-up that make a script one ``jax.distributed`` job.

A script adds the options with ``add_arguments(parser)``, checks them with
``check_arguments(args)`` (no JAX needed, so ``--help`` and bad values stay fast) and calls
``initialize(args)`` before its first JAX computation (before ``runtime.configure``, which
starts the backend). Every process then sees every device of the job (``jax.devices()``);
``_batch.simulate_batch`` / ``assess_batch`` shard a batch over them, each process builds
only its own shards (``jax.make_array_from_callback``), and the results are gathered to
every process (``_batch.to_host``). Only ``is_writer()`` (process 0) writes files.

Without any of the options ``initialize`` only sets the compilation cache, and the script
runs as one process, as before. ``docs/cluster.md`` has a SLURM recipe.
"""

from __future__ import annotations

import argparse
import pathlib

__all__ = ["add_arguments", "check_arguments", "initialize", "is_distributed", "is_writer", "broadcast_from_writer"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add ``--coordinator HOST:PORT``, ``--num-processes N``, ``--process-id I``,
    ``--auto-cluster`` and ``--compilation-cache DIR`` to ``parser`` (one argument group)."""
    g = parser.add_argument_group(
        "many processes / hosts (jax.distributed; docs/cluster.md)",
        "Give all three of --coordinator, --num-processes and --process-id (the same coordinator and count\n"
        "in every process), or --auto-cluster to read them from the cluster (SLURM, Open MPI, ...).",
    )
    g.add_argument("--coordinator", metavar="HOST:PORT", help="address of process 0's coordinator service")
    g.add_argument("--num-processes", type=int, metavar="N", help="processes in the job")
    g.add_argument("--process-id", type=int, metavar="I", help="this process's index, 0 to N-1 (0 writes the files)")
    g.add_argument(
        "--auto-cluster",
        action="store_true",
        help="jax.distributed.initialize() detects coordinator, count and index from the cluster's environment",
    )
    g.add_argument(
        "--compilation-cache",
        type=pathlib.Path,
        metavar="DIR",
        help="persistent XLA compilation cache (reused by later runs with the same shapes and settings)",
    )


def _explicit(args) -> list[str]:
    names = ("coordinator", "num_processes", "process_id")
    return ["--" + n.replace("_", "-") for n in names if getattr(args, n, None) is not None]


def check_arguments(args) -> None:
    """Raise ``ValueError`` (one line) for distributed options that cannot work; needs no JAX."""
    given = _explicit(args)
    auto = bool(getattr(args, "auto_cluster", False))
    if given and not auto and len(given) < 3:
        missing = sorted({"--coordinator", "--num-processes", "--process-id"} - set(given))
        verb = "needs" if len(given) == 1 else "need"
        raise ValueError(f"{' and '.join(given)} {verb} {' and '.join(missing)} as well (or --auto-cluster)")
    if args.coordinator is not None:
        host, sep, port = args.coordinator.rpartition(":")
        if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
            raise ValueError(f"--coordinator must be HOST:PORT with a port in 1-65535, got {args.coordinator!r}")
    if args.num_processes is not None and args.num_processes < 1:
        raise ValueError(f"--num-processes must be >= 1, got {args.num_processes}")
    if args.process_id is not None:
        if args.process_id < 0:
            raise ValueError(f"--process-id must be >= 0, got {args.process_id}")
        if args.num_processes is not None and args.process_id >= args.num_processes:
            raise ValueError(
                f"--process-id must be below --num-processes ({args.num_processes}), got {args.process_id}"
            )
    cache = getattr(args, "compilation_cache", None)
    if cache is not None and cache.exists() and not cache.is_dir():
        raise ValueError(f"--compilation-cache {cache}: not a folder")


def initialize(args) -> None:
    """Set up this process from the options of ``add_arguments``: the persistent compilation
    cache (``--compilation-cache``), and, when asked, ``jax.distributed.initialize`` with
    CPU collectives over Gloo (TCP). Call it once, before any JAX computation. Raises
    ``ValueError`` for bad options (``check_arguments``)."""
    check_arguments(args)
    import jax

    cache = getattr(args, "compilation_cache", None)
    if cache is not None:
        cache.mkdir(parents=True, exist_ok=True)
        jax.config.update("jax_compilation_cache_dir", str(cache))
    if not (_explicit(args) or args.auto_cluster):
        return
    # Cross-process collectives of the CPU backend (the gather of results): Gloo over TCP, which
    # needs no MPI. jax 0.10 defaults to it; set it so that an older default ("none") cannot bite.
    jax.config.update("jax_cpu_collectives_implementation", "gloo")
    jax.distributed.initialize(
        coordinator_address=args.coordinator, num_processes=args.num_processes, process_id=args.process_id
    )


def is_distributed() -> bool:
    """Whether this process is one of several (``jax.process_count() > 1``)."""
    import jax

    return jax.process_count() > 1


def is_writer() -> bool:
    """Whether this process writes the job's files (process 0; always true in a single process)."""
    import jax

    return jax.process_index() == 0


def broadcast_from_writer(values):
    """Process 0's ``values`` (a NumPy array or pytree of them, the same shapes in every
    process) in every process; ``values`` unchanged in a single process."""
    import jax

    if jax.process_count() == 1:
        return values
    from jax.experimental import multihost_utils

    return multihost_utils.broadcast_one_to_all(values, is_source=is_writer())


def share_start(run_key: str, order: list, todo, error) -> list:
    """Process 0's ``todo`` (a sub-list of ``order``, the trials every process enumerates
    alike) in every process, after checking that every process runs the same settings
    (``run_key``, a hex digest); process 0's ``error`` (a refused folder, a held lock) is
    raised in every process, so none waits for the others in a collective. In a single
    process: ``todo``, or ``error`` raised."""
    import numpy as np

    from .results import ResultsError

    if not is_distributed():
        if error is not None:
            raise error
        return todo
    from jax.experimental import multihost_utils

    key = np.frombuffer(bytes.fromhex(run_key), dtype=np.uint8).astype(np.int64)
    header = broadcast_from_writer(np.concatenate([[int(error is None), len(order)], key]))
    same = bool(header[1] == len(order) and np.array_equal(header[2:], key))
    agree = np.asarray(multihost_utils.process_allgather(np.array([int(same)]))).ravel()
    if not header[0]:
        if error is not None:
            raise error
        raise ResultsError("process 0 could not start the run (its error says why)")
    if not agree.all():
        raise ResultsError(
            f"process(es) {', '.join(map(str, np.flatnonzero(agree == 0)))} have other run settings than process 0: "
            "give every process the same options"
        )
    wanted = set(todo) if todo is not None else set()
    mask = broadcast_from_writer(np.array([item in wanted for item in order], dtype=np.int64))
    return [item for item, m in zip(order, mask, strict=True) if m]
