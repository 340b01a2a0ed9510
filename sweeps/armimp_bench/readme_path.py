"""What ``sweeps/bench_readme_path.py`` measures: the README's path against an entry point's
set-up and the numba reference, in alternating child processes of the script (``compare``)."""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import time

BATCH, SECONDS, SUBSTEPS = 24, 5.0, 100


def child(mode: str, repeats: int) -> None:
    """One process of the comparison: ``readme`` sets up as the README does
    (``aj.runtime.configure()``), ``plain`` only switches float64 on (plain XLA: importing
    the package sets nothing), ``numba`` runs the numba baseline on one thread."""
    import jax

    import armimp_jax as aj
    from armimp_jax import presets

    if mode == "readme":
        aj.runtime.configure()
    else:
        jax.config.update("jax_enable_x64", True)
    n = int(SECONDS * 1000)
    trials = aj.batch.stack_trials(
        [
            aj.make_trial(
                aj.IMBIC(), arm=presets.arm(1 + i % 4), friction=aj.LuGre(0.5 + 0.1 * (i % 7), 0.8 + 0.1 * (i % 7))
            )
            for i, j in ((i, i % 7) for i in range(BATCH))
        ]
    )
    f = jax.numpy.stack([aj.perturbation(jax.random.key(i), n, 2.25) for i in range(BATCH)])
    if mode == "numba":
        import numpy as np

        from . import numba_baseline

        f = np.asarray(f)

        def call():
            return numba_baseline.run(trials, f, SUBSTEPS)
    else:
        numerics = aj.Numerics(solver=aj.solvers.RK4(), substeps=SUBSTEPS)

        def call():
            return jax.block_until_ready(aj.simulate_batch(trials, f, numerics=numerics))

    call()  # compile
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        call()
        times.append(time.perf_counter() - t0)
    devices = 1 if mode == "numba" else len(jax.devices())
    print(f"{mode} {devices} {statistics.median(times)}")


def compare(a, *, script: str) -> None:
    """Time the processes (``readme``, ``configured``, ``numba`` where installed) in ``a.rounds``
    alternating rounds of the ``script``'s children and print the table."""
    try:
        import numba  # noqa: F401

        modes = ("readme", "plain", "numba")
    except ImportError:
        modes = ("readme", "plain")
    env = {**os.environ, "NUMBA_NUM_THREADS": "1"}
    best = {m: [] for m in modes}
    devices = {}
    for _ in range(a.rounds):
        for m in modes:
            out = subprocess.run(
                [sys.executable, script, "--child", m, "--repeats", str(a.repeats)],
                env=env,
                check=True,
                capture_output=True,
                text=True,
            ).stdout.split()
            best[m].append(float(out[-1]))
            devices[m] = out[-2]
    work = BATCH * SECONDS * 1000 * SUBSTEPS
    print(
        f"{BATCH} IMBIC trials of {SECONDS:g} s, RK4 at {SUBSTEPS} substeps, median per process, "
        f"load {os.getloadavg()[0]:.1f}"
    )
    print("| path | devices | s per call (each round) | M substeps/s (best) |")
    print("|---|---|---|---|")
    for m in modes:
        print(f"| {m} | {devices[m]} | {', '.join(f'{t:.3f}' for t in best[m])} | {work / min(best[m]) / 1e6:.1f} |")
    r = [x / y for x, y in zip(best["plain"], best["readme"], strict=True)]
    print(f"README path / plain XLA (speed): {', '.join(f'{x:.2f}' for x in r)}")
    if "numba" in best:
        print(
            "README path / numba (speed): "
            + ", ".join(f"{n / x:.1f}" for x, n in zip(best["readme"], best["numba"], strict=True))
        )
