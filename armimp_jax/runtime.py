"""Entry-point set-up: float64, one XLA device per CPU core, and XLA:CPU code-generation flags.

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
# XLA:CPU asks LLVM for 256-bit vectors by default. The batch axis of the RK4 loop is
# elementwise work on (B,) float64 arrays, and with 512-bit vectors (8 doubles) it runs
# 1.4-1.7x faster on AVX-512 cores, bit for bit the same results (sweeps/bench_simulate.py).
_VECTOR_FLAG = "--xla_cpu_prefer_vector_width"


def cpu_has_avx512() -> bool:
    """Whether the host CPU reports AVX-512F (read from ``/proc/cpuinfo``; False elsewhere)."""
    try:
        with open("/proc/cpuinfo") as f:
            return any(line.startswith("flags") and "avx512f" in line.split() for line in f)
    except OSError:
        return False


def _add_flag(flag: str, name: str) -> None:
    flags = os.environ.get("XLA_FLAGS", "")
    if name not in flags:
        os.environ["XLA_FLAGS"] = f"{flags} {flag}".strip()


def configure(
    *, host_devices: int | None = 0, hoist_small_loops: bool = True, vector_width: int | str | None = "auto"
) -> int:
    """Switch float64 on, set XLA:CPU code generation, and optionally split the CPU into devices.

    One jitted computation runs on one core of XLA:CPU; ``host_devices`` devices let a
    sharded batch use that many cores (see ``sweep.make_mesh``). ``0`` (default) means one
    per core (``os.cpu_count()``), ``None`` leaves the platform alone.
    ``hoist_small_loops`` adds the XLA:CPU option that compiles the inner RK4 loop into
    one kernel (it changes no forward result; gradients may differ in the last bits).
    ``vector_width`` (bits) is XLA:CPU's preferred SIMD width: ``"auto"`` asks for 512 on
    AVX-512 hosts and leaves the default elsewhere, ``None`` leaves it alone.
    Flags already in ``XLA_FLAGS`` win. Must run before the first JAX computation; on
    GPU/TPU hosts the CPU options are harmless and unused. Returns the number of devices
    JAX then sees.
    """
    jax.config.update("jax_enable_x64", True)
    if vector_width == "auto":
        vector_width = 512 if cpu_has_avx512() else None
    if vector_width is not None:
        if vector_width not in (128, 256, 512):
            raise ValueError(f"vector_width must be 128, 256, 512, 'auto' or None, got {vector_width!r}")
        _add_flag(f"{_VECTOR_FLAG}={vector_width}", _VECTOR_FLAG)
    if hoist_small_loops:
        _add_flag(_LOOP_FLAG, "xla_cpu_small_while_loop_byte_threshold")
    if host_devices is not None:
        n = host_devices or os.cpu_count() or 1
        flags = os.environ.get("XLA_FLAGS", "")
        _add_flag(f"{_FLAG}={n}", _FLAG)
        if jax.default_backend() == "cpu" and jax.device_count() != n and _FLAG not in flags:
            warnings.warn(
                f"configure(host_devices={n}) came after JAX started; it sees {jax.device_count()} device(s)",
                stacklevel=2,
            )
    return jax.device_count()
