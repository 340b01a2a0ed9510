"""The suite's isolation: the autouse fixture (tests/helpers.py, registered in tests/conftest.py)
fails a test that leaves the process's set-up changed, or that starts with it changed by a
fixture of a wider scope, and puts the set-up back; an entry point's ``configure()`` run
in-process leaves the suite's set-up as it is."""

import jax
from helpers import global_state, state_changes

import armimp_jax as aj
from armimp_jax import runtime

OFFENDERS = """
import os

import jax
import pytest

from armimp_jax import runtime

LANES = runtime.vector_lanes()


def test_narrows_the_vectors():
    os.environ["XLA_FLAGS"] = "--xla_cpu_prefer_vector_width=128"


def test_switches_float64_off():
    jax.config.update("jax_enable_x64", False)


def test_sets_flags_through_monkeypatch(monkeypatch):  # monkeypatch puts them back first: no offence
    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_prefer_vector_width=512")
    assert runtime.vector_lanes() == 8


@pytest.fixture(scope="module")
def narrows_for_the_module():
    os.environ["XLA_FLAGS"] = "--xla_cpu_prefer_vector_width=128"
    yield


def test_under_a_module_fixture_that_changes_the_set_up(narrows_for_the_module):
    pass


def test_after_the_offenders_the_set_up_is_back():
    assert runtime.vector_lanes() == LANES and jax.config.jax_enable_x64
"""


def test_the_fixture_fails_a_test_that_leaves_the_set_up_changed_and_puts_it_back(pytester):
    before = global_state()
    pytester.makeconftest("from helpers import global_state_unchanged, suite_state  # noqa: F401\n")
    pytester.makepyfile(test_offenders=OFFENDERS)
    result = pytester.runpytest_inprocess("-p", "no:cacheprovider")
    result.assert_outcomes(passed=4, errors=3)  # each offender's test passes, then its teardown fails
    text = result.stdout.str()
    assert "ERROR at teardown of test_narrows_the_vectors" in text
    assert "XLA_FLAGS added ['--xla_cpu_prefer_vector_width=128']" in text
    assert f"runtime.vector_lanes(): {before['runtime.vector_lanes()']} -> 2" in text
    assert "ERROR at teardown of test_switches_float64_off" in text and "jax_enable_x64: True -> False" in text
    assert "teardown of test_sets_flags_through_monkeypatch" not in text
    assert "ERROR at setup of test_under_a_module_fixture_that_changes_the_set_up" in text
    assert "the set-up changed between tests (a fixture of a wider scope)" in text
    assert global_state() == before


def test_every_entry_of_the_set_up_is_compared():
    before = global_state()
    assert before["jax_enable_x64"] and before["jax_numpy_rank_promotion"] == "raise"
    assert before["device count"] == jax.device_count() >= 1
    for name, other in [("device count", before["device count"] + 1), ("jax_numpy_rank_promotion", "allow")]:
        assert state_changes(before, dict(before, **{name: other})) == [f"{name}: {before[name]!r} -> {other!r}"]
    assert state_changes(before, dict(before)) == []


def test_an_entry_points_configure_run_in_process_leaves_the_suites_set_up():
    """What a script's main() does first (the README's call too): every option it sets is set
    already, so it changes nothing (without the suite's written-out vector width it would add
    512-bit vectors on an AVX-512 host)."""
    before = global_state()
    aj.runtime.configure()
    assert global_state() == before
    assert "--xla_cpu_prefer_vector_width=256" in before["XLA_FLAGS"] and runtime.vector_lanes() == 4
