"""What the scripts share (armimp_jax.study.runs.cli) and the benchmarks' timing helpers
(armimp_bench.timing): solver names held to the library's, ``--cases`` parsing,
round-robin timing, Markdown tables."""

import jax.numpy as jnp
import pytest

from armimp_bench import timing as _bench_run
from armimp_jax._solver.numerics import METHODS, named_solver
from armimp_jax.study.runs import cli as _cli


def test_the_scripts_solver_names_are_the_library_s():
    assert _cli.METHODS == METHODS
    for method in METHODS:
        assert _cli.solver(method) == named_solver(method)
    assert _cli.solver("rk4", kernel="reference") == named_solver("rk4", kernel="reference")


def test_cases_parse_or_fail_in_one_line(capsys):
    assert _cli.parse_cases("pd:0.3,imbic:1", "prog", "pd:0.3") == [("pd", 0.3), ("imbic", 1.0)]
    with pytest.raises(SystemExit) as exit_:
        _cli.parse_cases("pd,imbic:1", "prog", "pd:0.3,imbic:1")
    assert exit_.value.code == 2
    assert capsys.readouterr().err == "prog: error: --cases must look like pd:0.3,imbic:1; got 'pd,imbic:1'\n"


def test_alternate_times_the_runs_round_robin():
    calls = []

    def run(name):
        def call():
            calls.append(name)
            return jnp.zeros(2)

        return call

    times = _bench_run.alternate([run("a"), run("b")], 3)
    assert calls == ["a", "b"] * 3
    assert [len(t) for t in times] == [3, 3] and all(s >= 0 for t in times for s in t)


def test_markdown_table_and_save(tmp_path):
    text = _bench_run.markdown_table("Caption:", ("a", "b c"), [(1, "x"), ("2.50", "y")])
    assert text == "Caption:\n\n| a | b c |\n|---|---|\n| 1 | x |\n| 2.50 | y |"
    _bench_run.save_table(tmp_path / "out", "t", text, [dict(a=1)])
    assert (tmp_path / "out" / "t.md").read_text() == text + "\n"
    assert (tmp_path / "out" / "t.json").read_text() == '[\n {\n  "a": 1\n }\n]'


def test_the_reaches_a_spread_needs_follow_one_over_root_r_minus_one():
    import numpy as np

    from armimp_bench.movement_model import needed

    rng = np.random.default_rng(1)
    true = np.array([100.0, -50.0])
    est = true + rng.standard_normal((20000, 2)) * np.array([3.0, 2.0])  # spreads of 40-reach ensembles
    n = needed(est, true, np.full(20000, 40), precision=0.1)
    # +-10% at 95% needs SE / |value| = 0.1 / 1.96: (1.96 * 3 / 10)^2 * 39 + 1 = 14.5; the y entry 25.0
    np.testing.assert_allclose(n, [1 + 39 * (1.96 * 3.0 / 10.0) ** 2, 1 + 39 * (1.96 * 2.0 / 5.0) ** 2], rtol=0.03)
