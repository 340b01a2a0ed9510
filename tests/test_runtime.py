"""armimp_jax.runtime: the XLA:CPU options an entry point sets, and the vector lanes they imply."""

import os


def test_configure_merges_xla_extra_options(monkeypatch):
    from armimp_jax import runtime

    waits = (
        " --xla_cpu_collective_call_terminate_timeout_seconds=86400 --xla_cpu_collective_timeout_seconds=86400"
        " --xla_cpu_collective_call_warn_stuck_timeout_seconds=600"
    )
    monkeypatch.setenv("XLA_FLAGS", "--xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold=5")
    runtime.configure(host_devices=None, vector_width=None)
    # one flag holds all extra options; a value the caller set wins
    assert os.environ["XLA_FLAGS"] == (
        "--xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold=5,xla_cpu_disable_loop_unrolling" + waits
    )
    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_prefer_vector_width=256 --xla_cpu_collective_timeout_seconds=5")
    runtime.configure(host_devices=None, vector_width=512, unroll_loops=True)
    assert os.environ["XLA_FLAGS"] == (
        "--xla_cpu_prefer_vector_width=256 --xla_cpu_collective_timeout_seconds=5 "
        "--xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold=1000000"
        " --xla_cpu_collective_call_terminate_timeout_seconds=86400"
        " --xla_cpu_collective_call_warn_stuck_timeout_seconds=600"
    )


def test_vector_lanes_follow_the_xla_vector_width(monkeypatch):
    from armimp_jax import runtime

    monkeypatch.setenv("XLA_FLAGS", "--xla_force_host_platform_device_count=2")
    assert runtime.vector_lanes() == 4  # XLA:CPU's default 256-bit vectors
    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_prefer_vector_width=512 --xla_force_host_platform_device_count=2")
    assert runtime.vector_lanes() == 8
    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_prefer_vector_width=128")
    assert runtime.vector_lanes() == 2


def _devices_after_import(
    env_extra: dict, code: str = "import armimp_jax as aj, jax; aj.simulate; print(jax.device_count())"
) -> str:
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k not in ("XLA_FLAGS", "ARMIMP_JAX_CPU_DEVICES")}
    out = subprocess.run([sys.executable, "-c", code], env=env | env_extra, capture_output=True, text=True)
    return out.stdout.strip() or out.stderr.strip().splitlines()[-1]


def test_importing_the_library_changes_nothing_and_configure_sets_up():
    """No XLA flag and no setting of JAX's changes at import (nor when the package's JAX
    modules load); ``configure`` asks for one CPU device per core unless the caller chose."""
    cores = os.cpu_count() or 1
    # importing the package alone imports no JAX (a script's --help stays fast)
    assert _devices_after_import({}, "import sys, armimp_jax; print('jax' in sys.modules)") == "False"
    unchanged = (
        "import os, armimp_jax as aj, jax; aj.simulate; print(jax.device_count(), repr(os.environ.get('XLA_FLAGS')))"
    )
    assert _devices_after_import({}, unchanged) == "1 None"
    configured = (
        "import armimp_jax as aj, jax; aj.runtime.configure(); print(jax.device_count(), jax.config.jax_enable_x64)"
    )
    assert _devices_after_import({}, configured) == f"{cores} True"
    assert _devices_after_import({"ARMIMP_JAX_CPU_DEVICES": "1"}, configured) == "1 True"
    assert _devices_after_import({"XLA_FLAGS": "--xla_force_host_platform_device_count=3"}, configured) == "3 True"
    assert _devices_after_import({"ARMIMP_JAX_CPU_DEVICES": "two"}, configured) == (
        "ValueError: ARMIMP_JAX_CPU_DEVICES must be a whole number >= 1, got 'two'"
    )


def test_the_compilation_cache_folder_follows_the_environment(monkeypatch, tmp_path):
    from armimp_jax import runtime

    monkeypatch.setenv("ARMIMP_JAX_CACHE_DIR", str(tmp_path / "c"))
    assert runtime.compilation_cache_dir() == str(tmp_path / "c")
    for off in ("off", "", "0", "None"):
        monkeypatch.setenv("ARMIMP_JAX_CACHE_DIR", off)
        assert runtime.compilation_cache_dir() is None
    monkeypatch.delenv("ARMIMP_JAX_CACHE_DIR")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert runtime.compilation_cache_dir() == str(tmp_path / "xdg" / "armimp_jax" / "jax")


def test_backend_started_asks_jax_without_changing_its_settings():
    code = (
        "import jax; from armimp_jax import runtime; "
        "before = runtime.backend_started(); jax.devices(); "
        "print(before, runtime.backend_started(), jax.config.jax_num_cpu_devices)"
    )
    assert _devices_after_import({}, code) == "False True -1"
