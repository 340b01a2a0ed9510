"""armimp_jax.study.stats: the one t-interval of a mean (sweeps, the reproduction's conditions and
claims, their figures) and its flat form in a sweep's summary."""

import math

import numpy as np
import pytest
from scipy import stats as sps

from armimp_jax.paper import claims
from armimp_jax.study import stats, sweep


def test_mean_ci_is_the_t_interval_of_the_mean():
    rng = np.random.default_rng(3)
    for n in (2, 3, 7):
        v = rng.normal(5.0, 2.0, n)
        st = stats.mean_ci(v)
        half = sps.t.ppf(0.975, n - 1) * np.std(v, ddof=1) / math.sqrt(n)
        assert st.mean == pytest.approx(v.mean(), rel=1e-15) and st.sd == pytest.approx(np.std(v, ddof=1), rel=1e-15)
        assert st.half == pytest.approx(half, rel=1e-14)
        # the interval covers the mean at the level asked for: a wider one at 99%
        assert stats.mean_ci(v, 0.99).half > st.half
    assert stats.mean_ci([4.0]) == (4.0, 0.0, None)  # one seed: no interval
    empty = stats.mean_ci([])
    assert math.isnan(empty.mean) and math.isnan(empty.sd) and empty.half is None


def test_mean_ci_is_elementwise_for_arrays_and_scalars_come_back_as_floats():
    v = np.array([[[1.0, 2.0], [3.0, 4.0]], [[3.0, 2.0], [5.0, 8.0]]])  # 2 seeds of a (2, 2) metric
    st = stats.mean_ci(v)
    np.testing.assert_array_equal(st.mean, [[2.0, 2.0], [4.0, 6.0]])
    np.testing.assert_allclose(st.half, sps.t.ppf(0.975, 1) * np.std(v, axis=0, ddof=1) / math.sqrt(2))
    assert type(stats.mean_ci([1.0, 2.0]).mean) is float
    assert stats.mean_ci(np.empty((0, 2, 2))).mean.shape == (2, 2)


def test_seed_stats_leave_out_undefined_values():
    values = [1.0, None, float("nan"), 3.0, float("inf")]
    st = stats.seed_stats(values)
    ref = stats.mean_ci([1.0, 3.0])
    assert st == dict(n=2, mean=2.0, sd=ref.sd, ci_lo=2.0 - ref.half, ci_hi=2.0 + ref.half)
    one = stats.seed_stats([None, 5.0])
    assert one["n"] == 1 and one["sd"] == 0.0 and math.isnan(one["ci_lo"]) and math.isnan(one["ci_hi"])
    assert stats.seed_stats([])["n"] == 0 and math.isnan(stats.seed_stats([])["mean"])


def test_every_study_uses_one_level_and_one_interval():
    assert claims.CI_LEVEL is stats.CI_LEVEL
    assert claims.mean_ci is stats.mean_ci and sweep.seed_stats is stats.seed_stats
