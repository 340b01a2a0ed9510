"""Entry-point set-up: float64, one XLA device per CPU core, and XLA:CPU code-generation flags.

Importing ``armimp_jax`` changes no setting of JAX's and no XLA flag. ``configure`` is the
set-up, called once at program start, before the first JAX computation, by every script
and by the README's library example: it (1) switches float64 on; (2) asks JAX for one CPU
device per core (``jax_num_cpu_devices``; ``ARMIMP_JAX_CPU_DEVICES`` chooses another count),
because one jitted computation runs on one core of XLA:CPU and ``simulate_batch``, the
sweeps and the tests shard their batches over the devices they find; (3) adds two XLA:CPU
code-generation options that XLA refuses as per-compilation options (they live in
``xla_backend_extra_options``, a map that ``jax.jit(compiler_options=...)`` cannot set), so
the environment is the only place for them, and 512-bit vectors on AVX-512 hosts; (4) lets
the devices wait for each other at a collective for a day instead of XLA:CPU's 40 s, after
which it aborts the process; and (5) keeps JAX's compiled programs in
``compilation_cache_dir()``, so a second run loads them instead of compiling them again.
A caller's own settings win (a device count already set in ``XLA_FLAGS``, options already
in ``XLA_FLAGS``); single computations still run on the first device.
"""

from __future__ import annotations

import os
import re
import warnings

_FLAG = "--xla_force_host_platform_device_count"
_EXTRA = "--xla_backend_extra_options"
# Lets XLA:CPU run a small while loop (our inner RK4 scan) as one kernel instead of
# dispatching every iteration, much faster at small batches (sweeps/bench_simulate.py).
_LOOP_OPTION = ("xla_cpu_small_while_loop_byte_threshold", "1000000")
# Inside that kernel every fusion is a loop over the per-device batch, a few vectors
# long, which LLVM would unroll into slower straight-line code at small per-device batches
# (sweeps/bench_simulate.py --compare-unrolling).
_NO_UNROLL_OPTION = ("xla_cpu_disable_loop_unrolling", None)
# XLA:CPU asks LLVM for 256-bit vectors by default. The batch axis of the RK4 loop is
# elementwise work on (B,) float64 arrays, which 512-bit vectors run faster on AVX-512
# cores, bit for bit the same (sweeps/bench_simulate.py).
_VECTOR_FLAG = "--xla_cpu_prefer_vector_width"
_DEFAULT_VECTOR_WIDTH = 256  # XLA:CPU's own default for the flag above
# A computation split over CPU devices meets at its collectives (a mean over a sharded batch
# of noise draws, say); XLA:CPU aborts the process when one device arrives 40 s after the
# others, which a loaded host or a long uneven share reaches. Wait instead.
_COLLECTIVE_FLAGS = (
    ("--xla_cpu_collective_call_terminate_timeout_seconds", 86400),
    ("--xla_cpu_collective_timeout_seconds", 86400),
    ("--xla_cpu_collective_call_warn_stuck_timeout_seconds", 600),
)


CACHE_ENV = "ARMIMP_JAX_CACHE_DIR"
# Every program gets a file (JAX's default skips those under 1 s): a second identify of a lab's
# recording loads hundreds of small ones, which together cost as much as the few large ones.
_CACHE_MIN_COMPILE_S = 0.0


def compilation_cache_dir() -> str | None:
    """Where ``configure`` keeps compiled programs: ``$ARMIMP_JAX_CACHE_DIR`` if set (``off`` or
    empty: no cache), else ``$XDG_CACHE_HOME/armimp_jax/jax`` (``~/.cache/armimp_jax/jax``).
    JAX keys each file by the program, the JAX version, the device and the XLA options, so a
    stale one is never loaded; delete the folder to reclaim its space."""
    text = os.environ.get(CACHE_ENV)
    if text is not None:
        return None if text.strip().lower() in ("", "off", "0", "none") else os.path.expanduser(text)
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "armimp_jax", "jax")


def use_compilation_cache(path: str | None) -> str | None:
    """Keep JAX's compiled programs in ``path`` (``None``: leave JAX's setting alone). Returns the
    folder in use."""
    import jax

    if path is not None:
        jax.config.update("jax_compilation_cache_dir", path)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", _CACHE_MIN_COMPILE_S)
    return jax.config.jax_compilation_cache_dir


def backend_started() -> bool:
    """Whether a JAX backend has started in this process (imports JAX).

    Asked through public API: JAX refuses to change ``jax_num_cpu_devices`` once a backend
    exists (its documented rule: set it before JAX is initialised), so a change that is taken
    means none exists yet; the setting is put back at once."""
    import jax

    value = jax.config.jax_num_cpu_devices
    try:
        jax.config.update("jax_num_cpu_devices", value + 1)
    except RuntimeError:
        return True
    jax.config.update("jax_num_cpu_devices", value)
    return False


def _add_collective_timeouts() -> None:
    for flag, seconds in _COLLECTIVE_FLAGS:
        _add_flag(f"{flag}={seconds}", flag)


def default_cpu_devices() -> int:
    """The CPU device count ``configure`` asks for by default: ``ARMIMP_JAX_CPU_DEVICES`` if
    set (a whole number >= 1), else one per core (``os.cpu_count()``)."""
    text = os.environ.get("ARMIMP_JAX_CPU_DEVICES")
    if text is None:
        return os.cpu_count() or 1
    if not text.strip().isdigit() or int(text) < 1:
        raise ValueError(f"ARMIMP_JAX_CPU_DEVICES must be a whole number >= 1, got {text!r}")
    return int(text)


def vector_lanes() -> int:
    """float64 lanes of the SIMD vectors XLA:CPU generates code for: the width set by
    ``--xla_cpu_prefer_vector_width`` in ``XLA_FLAGS`` (XLA's default 256 bits if unset),
    divided by 64. ``simulate_batch`` pads per-device batches to whole vectors of this size."""
    match = re.search(rf"{_VECTOR_FLAG}=(\d+)", os.environ.get("XLA_FLAGS", ""))
    return max(1, (int(match.group(1)) if match else _DEFAULT_VECTOR_WIDTH) // 64)


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


def _add_extra_option(name: str, value: str | None) -> None:
    """Add ``name[=value]`` to XLA's backend extra options (one comma-separated flag)
    unless the option is already there."""
    option = name if value is None else f"{name}={value}"
    flags = os.environ.get("XLA_FLAGS", "")
    match = re.search(rf"{_EXTRA}=(\S*)", flags)
    if match is None:
        os.environ["XLA_FLAGS"] = f"{flags} {_EXTRA}={option}".strip()
    elif name not in {item.split("=")[0] for item in match.group(1).split(",")}:
        merged = f"{match.group(1)},{option}" if match.group(1) else option
        os.environ["XLA_FLAGS"] = flags[: match.start(1)] + merged + flags[match.end(1) :]


def configure(
    *,
    host_devices: int | None = 0,
    hoist_small_loops: bool = True,
    unroll_loops: bool = False,
    vector_width: int | str | None = "auto",
    compilation_cache: bool = True,
) -> int:
    """Switch float64 on, set XLA:CPU code generation, and optionally split the CPU into devices.

    One jitted computation runs on one core of XLA:CPU; ``host_devices`` devices let a
    sharded batch use that many cores (see ``armimp_jax._batch.make_mesh``). ``0`` (default) means
    ``default_cpu_devices()`` (one per core unless ``ARMIMP_JAX_CPU_DEVICES`` says otherwise),
    ``None`` leaves the platform alone.
    ``hoist_small_loops`` adds the XLA:CPU option that compiles the inner RK4 loop into
    one kernel. ``unroll_loops=False`` adds the option that stops LLVM unrolling the
    short per-fusion loops over the batch inside that kernel (faster at small per-device
    batches). Both change where LLVM contracts ``a*b + c`` into an FMA, so
    results may move in their last bits (bounded in ``tests/test_batch.py``,
    ``test_entry_point_codegen_options_agree_with_plain_xla_to_round_off``).
    ``vector_width`` (bits) is XLA:CPU's preferred SIMD width: ``"auto"`` asks for 512 on
    AVX-512 hosts and leaves the default elsewhere, ``None`` leaves it alone.
    ``compilation_cache``: keep compiled programs in ``compilation_cache_dir()`` across runs.
    Flags already in ``XLA_FLAGS`` win. Must run before the first JAX computation; on
    GPU/TPU hosts the CPU options are harmless and unused. Returns the number of devices
    JAX then sees.
    """
    import jax

    jax.config.update("jax_enable_x64", True)
    if compilation_cache:
        use_compilation_cache(compilation_cache_dir())
    present = os.environ.get("XLA_FLAGS", "")
    if (not hoist_small_loops and _LOOP_OPTION[0] in present) or (unroll_loops and _NO_UNROLL_OPTION[0] in present):
        warnings.warn(
            "configure(hoist_small_loops=False / unroll_loops=True) cannot take out XLA:CPU options already in "
            "XLA_FLAGS (an earlier configure, or the caller, put them there)",
            stacklevel=2,
        )
    if vector_width == "auto":
        vector_width = 512 if cpu_has_avx512() else None
    if vector_width is not None:
        if vector_width not in (128, 256, 512):
            raise ValueError(f"vector_width must be 128, 256, 512, 'auto' or None, got {vector_width!r}")
        _add_flag(f"{_VECTOR_FLAG}={vector_width}", _VECTOR_FLAG)
    if hoist_small_loops:
        _add_extra_option(*_LOOP_OPTION)
    if not unroll_loops:
        _add_extra_option(*_NO_UNROLL_OPTION)
    _add_collective_timeouts()
    if host_devices is not None:
        n = host_devices or default_cpu_devices()
        if _FLAG in os.environ.get("XLA_FLAGS", ""):
            pass  # the caller's own count wins
        elif not backend_started():
            jax.config.update("jax_num_cpu_devices", n)
        elif jax.default_backend() == "cpu" and jax.device_count() != n:
            warnings.warn(
                f"configure(host_devices={n}) came after JAX started; it sees {jax.device_count()} device(s)",
                stacklevel=2,
            )
    return jax.device_count()
