"""Entry-point set-up: float64 and one XLA device per CPU core.

Library code never changes JAX's configuration; scripts call ``configure`` once at start.
"""

from __future__ import annotations

import os
import warnings

import jax

_FLAG = "--xla_force_host_platform_device_count"


def configure(*, host_devices: int | None = 0) -> int:
    """Switch float64 on and (optionally) split the host CPU into several XLA devices.

    One jitted computation runs on one core of XLA:CPU; ``host_devices`` devices let a
    sharded batch use that many cores (see ``sweep.make_mesh``). ``0`` (default) means one
    per core (``os.cpu_count()``), ``None`` leaves the platform alone. Must run before the
    first JAX computation; on GPU/TPU hosts the CPU split is harmless and unused.
    Returns the number of devices JAX then sees.
    """
    jax.config.update("jax_enable_x64", True)
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
