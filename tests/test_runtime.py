"""armimp_jax.runtime: the XLA:CPU options an entry point sets, and the vector lanes they imply."""

import os


def test_configure_merges_xla_extra_options(monkeypatch):
    from armimp_jax import runtime

    monkeypatch.setenv("XLA_FLAGS", "--xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold=5")
    runtime.configure(host_devices=None, vector_width=None)
    # one flag holds all extra options; a value the caller set wins
    assert os.environ["XLA_FLAGS"] == (
        "--xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold=5,xla_cpu_disable_loop_unrolling"
    )
    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_prefer_vector_width=256")
    runtime.configure(host_devices=None, vector_width=512, unroll_loops=True)
    assert os.environ["XLA_FLAGS"] == (
        "--xla_cpu_prefer_vector_width=256 --xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold=1000000"
    )


def test_vector_lanes_follow_the_xla_vector_width(monkeypatch):
    from armimp_jax import runtime

    monkeypatch.setenv("XLA_FLAGS", "--xla_force_host_platform_device_count=2")
    assert runtime.vector_lanes() == 4  # XLA:CPU's default 256-bit vectors
    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_prefer_vector_width=512 --xla_force_host_platform_device_count=2")
    assert runtime.vector_lanes() == 8
    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_prefer_vector_width=128")
    assert runtime.vector_lanes() == 2
