"""Entry-point set-up: float64 and one XLA device per CPU core.

Library code never changes JAX's configuration; scripts call ``configure`` once at start.
"""

from __future__ import annotations

import os
import warnings

import jax

_FLAG = "--xla_force_host_platform_device_count"
# Lets XLA:CPU run a small while loop (our inner RK4 scan) as one kernel instead of
# dispatching every iteration: 1.4-4x faster at batch 1-24 (sweeps/bench_simulate.py).
_LOOP_FLAG = "--xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold=1000000"


def configure(*, host_devices: int | None = 0, hoist_small_loops: bool = True) -> int:
    """Switch float64 on and (optionally) split the host CPU into several XLA devices.

    One jitted computation runs on one core of XLA:CPU; ``host_devices`` devices let a
    sharded batch use that many cores (see ``sweep.make_mesh``). ``0`` (default) means one
    per core (``os.cpu_count()``), ``None`` leaves the platform alone. Must run before the
    first JAX computation; on GPU/TPU hosts the CPU split is harmless and unused.
    ``hoist_small_loops`` adds the XLA:CPU option that compiles the inner RK4 loop into
    one kernel (it changes no forward result; gradients may differ in the last bits).
    Returns the number of devices JAX then sees.
    """
    jax.config.update("jax_enable_x64", True)
    if hoist_small_loops and "xla_cpu_small_while_loop_byte_threshold" not in os.environ.get("XLA_FLAGS", ""):
        os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {_LOOP_FLAG}".strip()
    if host_devices is not None:
        n = host_devices or os.cpu_count() or 1
        flags = os.environ.get("XLA_FLAGS", "")
        if _FLAG not in flags:
            os.environ["XLA_FLAGS"] = f"{flags} {_FLAG}={n}".strip()
        if jax.default_backend() == "cpu" and jax.device_count() != n and _FLAG not in flags:
            warnings.warn(
                f"configure(host_devices={n}) came after JAX started; it sees {jax.device_count()} device(s)",
                stacklevel=2,
            )
    return jax.device_count()
