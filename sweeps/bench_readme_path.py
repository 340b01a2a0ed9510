"""Benchmark: the README's path against an entry point's set-up, and the numba reference.

Three child processes, alternating, each timing 24 IMBIC trials (5 s, the four arms and
seven friction levels cycled, RK4 at 100 substeps: the issue's workload) through
``aj.simulate_batch``: ``readme`` (float64 switched on, nothing configured: what the README
shows), ``configured`` (after ``aj.runtime.configure()``) and, with numba installed,
``numba`` (``sweeps/numba_baseline.py`` on one thread). Compile excluded (the first call),
``block_until_ready``, median of ``--repeats`` calls per process, ratios from one run.

    python sweeps/bench_readme_path.py [--repeats 5] [--rounds 2]
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import time

from _cli import Parser

BATCH, SECONDS, SUBSTEPS = 24, 5.0, 100


def child(mode: str, repeats: int) -> None:
    import jax

    jax.config.update("jax_enable_x64", True)
    import armimp_jax as aj
    from armimp_jax import presets

    if mode == "configured":
        aj.runtime.configure(compilation_cache=False)  # compile times are measured
    n = int(SECONDS * 1000)
    trials = aj.stack_trials(
        [
            aj.make_trial(
                aj.IMBIC(), arm=presets.arm(1 + i % 4), friction=aj.LuGre(0.5 + 0.1 * (i % 7), 0.8 + 0.1 * (i % 7))
            )
            for i, j in ((i, i % 7) for i in range(BATCH))
        ]
    )
    f = jax.numpy.stack([aj.perturbation(jax.random.key(i), n, 2.25) for i in range(BATCH)])
    if mode == "numba":
        import numba_baseline
        import numpy as np

        f = np.asarray(f)

        def call():
            return numba_baseline.run(trials, f, SUBSTEPS)
    else:
        numerics = aj.Numerics(solver=aj.RK4(), substeps=SUBSTEPS)

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


def main(argv=None):
    p = Parser(prog="bench_readme_path", description=__doc__.split("\n\n")[0])
    p.add_argument("--repeats", type=int, default=5, help="timed calls per process (default 5)")
    p.add_argument("--rounds", type=int, default=2, help="alternating rounds of the processes (default 2)")
    p.add_argument("--child", default=None, help="internal: run one process of the comparison")
    a = p.parse_args(sys.argv[1:] if argv is None else argv)
    if a.child:
        child(a.child, a.repeats)
        return
    try:
        import numba  # noqa: F401

        modes = ("readme", "configured", "numba")
    except ImportError:
        modes = ("readme", "configured")
    env = {**os.environ, "NUMBA_NUM_THREADS": "1"}
    best = {m: [] for m in modes}
    devices = {}
    for _ in range(a.rounds):
        for m in modes:
            out = subprocess.run(
                [sys.executable, __file__, "--child", m, "--repeats", str(a.repeats)],
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
    r = [x / y for x, y in zip(best["configured"], best["readme"], strict=True)]
    print(f"README path / configured (speed): {', '.join(f'{x:.2f}' for x in r)}")
    if "numba" in best:
        print(
            "README path / numba (speed): "
            + ", ".join(f"{n / x:.1f}" for x, n in zip(best["readme"], best["numba"], strict=True))
        )


if __name__ == "__main__":
    main()
