"""identify's checks of its own answer: the classical cross-check (``selfcheck.cross_check``), the
last step taken only when a binding confirms it (``search._final_step``), and the words a lab
reads when either fails. The simulations are stubbed: the arithmetic and the bookkeeping only
(the checks' effect on real recordings is measured by ``sweeps/bench_identify_matrix.py``)."""

import jax
import numpy as np
import pytest
import scipy.stats

from armimp_jax._identification import indirect, search, selfcheck
from armimp_jax._identification import layout as lay
from armimp_jax._identification import result as result_mod

R = 64  # draws of the final binding
K = 32  # the check's (its first ones)


def _problem(count=1):
    layout = lay.make_layout(("arm.stiffness",))  # four internal entries, one statistic each
    keys = jax.random.split(jax.random.key(0), R)
    part = search.Part(layout, "model", None, keys, "efficient", np.arange(4), count)
    return search.Problem((part,), None, 2, True, np.zeros(4), np.zeros(0, int), np.zeros(0), 0.0, 4, chord=True)


def _draws(rng, noise):
    """Efficient statistics ``s`` of the final binding and the classical fits ``c`` of its first
    ``K`` draws: each classical fit the draw's own re-estimate (``S = I``) plus independent noise
    of SD ``noise``, so their difference spreads with that SD alone."""
    s = rng.normal(size=(R, 4)) * 10.0
    c = 100.0 + s[:K] + noise * rng.normal(size=(K, 4))
    return s, c


def _check(monkeypatch, s, c, own, count=1, diverged=None):
    calls = []

    def draws(layout, model, p, f, keys, numerics, arm_stat=None, stat_layout=None):
        calls.append((keys.shape[0], arm_stat, stat_layout))
        div = np.zeros(keys.shape[0], bool) if diverged is None else diverged
        return c, div

    monkeypatch.setattr(indirect, "binding_draws", draws)
    monkeypatch.setattr(selfcheck, "_classical_statistics", lambda *a: own)
    labels = [f"arm.stiffness[{i},{j}]" for i in (0, 1) for j in (0, 1)]
    recorded = [(0, None, None)] * count
    found, dropped = selfcheck.cross_check(_problem(count), np.zeros(4), s, np.eye(4), recorded, labels)
    return found, dropped, calls


def test_an_entry_beyond_the_combined_uncertainty_is_named_with_both_values(monkeypatch):
    """The recording's classical fit 6 combined SEs off the model's prediction on one entry and on
    its prediction elsewhere: that entry alone is named, with the recorded and predicted values;
    the combined SE is the paired difference's (the classical fit less the draw's own
    re-estimate) plus the prediction's own Monte Carlo error, not either fit's spread alone."""
    rng = np.random.default_rng(1)
    s, c = _draws(rng, noise=2.0)
    diff = (c - c.mean(axis=0)) - (s[:K] - s.mean(axis=0))
    se = np.sqrt(diff.var(axis=0, ddof=1) + c.var(axis=0, ddof=1) / K)
    own = c.mean(axis=0) + np.array([0.0, 6.0 * se[1], 0.5 * se[2], 0.0])
    found, dropped, calls = _check(monkeypatch, s, c, own)
    assert dropped == 0 and calls == [(K, None, lay.make_layout(("arm.stiffness",)))]
    (d,) = found
    assert d.label == "arm.stiffness[0,1]" and d.z == pytest.approx(6.0)
    assert d.classical == pytest.approx(own[1]) and d.predicted == pytest.approx(c[:, 1].mean())
    assert d.combined_se == pytest.approx(se[1])
    # the classical fit's own spread (about 10) is far wider: the pairing is what makes the check sharp
    assert np.all(c.std(axis=0) > 3.0 * se)


def test_the_threshold_is_bonferroni_over_the_entries_at_the_false_alarm_rate(monkeypatch):
    """Just inside the bound: silent; just outside: named. The bound is the t quantile of the
    check's draws at ``FALSE_ALARM`` shared over the entries."""
    bound = selfcheck.threshold(K, 4)
    assert bound == pytest.approx(scipy.stats.t.ppf(1.0 - selfcheck.FALSE_ALARM / 8, K - 1))
    rng = np.random.default_rng(2)
    s, c = _draws(rng, noise=2.0)
    diff = (c - c.mean(axis=0)) - (s[:K] - s.mean(axis=0))
    se = np.sqrt(diff.var(axis=0, ddof=1) + c.var(axis=0, ddof=1) / K)
    for factor, named in ((0.99, 0), (1.01, 1)):
        own = c.mean(axis=0) + np.array([0.0, 0.0, factor * bound * se[2], 0.0])
        assert len(_check(monkeypatch, s, c, own)[0]) == named


def test_repeated_recordings_and_diverged_draws(monkeypatch):
    """Four recordings matched by their mean: the recordings' share of the combined variance is a
    quarter. Draws that diverged are left out and counted; fewer than 3 sound: not checked."""
    rng = np.random.default_rng(3)
    s, c = _draws(rng, noise=2.0)
    diff = (c - c.mean(axis=0)) - (s[:K] - s.mean(axis=0))
    se4 = np.sqrt(diff.var(axis=0, ddof=1) / 4 + c.var(axis=0, ddof=1) / K)
    own = c.mean(axis=0) + np.array([5.0 * se4[0], 0.0, 0.0, 0.0])
    (d,), _, _ = _check(monkeypatch, s, c, own, count=4)
    assert d.z == pytest.approx(5.0)
    diverged = np.zeros(K, bool)
    diverged[: K - 2] = True
    assert _check(monkeypatch, s, c, own, diverged=diverged)[:2] == ([], K - 2)


def test_the_warning_gives_both_values_and_what_to_change():
    d = selfcheck.Disagreement("arm.stiffness[0,0]", 259.0, 470.0, 50.0, -4.2)
    (w,) = result_mod._disagree([d], {"arm.stiffness[0,0]": 484.0}, {"arm.stiffness[0,0]": 76.0})
    assert "arm.stiffness[0,0] 484 +- 76 here, the classical fit 259" in w and "give 470 (4.2 combined SEs" in w
    assert result_mod.ADVICE in w and "settings" not in w
    assert result_mod._disagree([], {}, {}) == []


def test_the_last_step_is_taken_only_where_a_binding_confirms_it(monkeypatch):
    """``search._final_step``: the new point's mismatch is its binding's, not the linear
    prediction's (which is zero: the step solves the linearised match), and the search goes on from
    there; where that binding diverges the step is not taken and the search ends unsettled."""
    problem = _problem()._replace(b=np.ones(4))
    state = search.Search(
        np.zeros(4),
        np.zeros(4),
        np.zeros((R, 4)),
        2.0,
        np.eye(4),
        np.zeros(4),
        np.ones(4),
        np.ones(4),
        3,
        (),
        (),
        False,
        R,
        2,
    )
    stats = np.random.default_rng(4).normal(size=(R, 4))
    monkeypatch.setattr(search, "_binding", lambda problem, p, draws=None: (np.full(4, 0.9), stats, False))
    out = search._final_step(problem, state, np.ones(4))
    np.testing.assert_array_equal(out.p, np.ones(4))
    w = 1.0 / stats.var(axis=0, ddof=1)
    assert out.cost == pytest.approx(0.5 * np.sum(w * 0.01)) and out.iterations == 4 and not out.done
    monkeypatch.setattr(search, "_binding", lambda problem, p, draws=None: (np.full(4, 0.9), stats, True))
    out = search._final_step(problem, state, np.ones(4))
    assert out.done and np.array_equal(out.p, state.p) and "went unstable" in out.problems[0]
