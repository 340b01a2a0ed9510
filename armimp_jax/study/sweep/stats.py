"""Seed statistics of every study: the t-interval of a mean, and thresholds with bootstrap intervals.

One confidence level (``CI_LEVEL``) and one interval of the mean (``mean_ci``) serve the
sweep's summary, the reproduction's condition means and claims, and their figures.
``seed_stats`` is the flat form a sweep's ``summary.json`` holds. ``first_crossing`` and
``bootstrap_crossing`` find where a curve over a grid (e.g. ``phi_T`` against ``tau_c``)
crosses a level, with a percentile bootstrap interval over seeds.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from typing import NamedTuple

import numpy as np
from scipy import stats

CI_LEVEL = 0.95  # two-sided level of every interval


class MeanCI(NamedTuple):
    """A mean over seeds: ``mean``, sample standard deviation ``sd`` (``n - 1``) and the
    half-width ``half`` of the two-sided t-interval of the mean (``None`` under two values:
    one seed gives no interval). Scalars for scalar values, arrays for array values."""

    mean: float | np.ndarray
    sd: float | np.ndarray
    half: float | np.ndarray | None


def mean_ci(values, level: float = CI_LEVEL) -> MeanCI:
    """The mean, standard deviation and t-interval half-width of ``values`` along axis 0
    (elementwise for arrays: ``(n, ...)``; ``n - 1`` degrees of freedom).

    Values are used as given (a NaN gives a NaN mean): callers leave diverged trials out
    first. For no values, ``mean`` and ``sd`` are NaN; for one, ``sd`` is 0; ``half`` is
    ``None`` under two values."""
    v = np.asarray(values, dtype=float)
    n = v.shape[0]
    if n == 0:
        nan = np.full(v.shape[1:], np.nan)
        return MeanCI(_plain(nan), _plain(nan), None)
    mean = v.mean(axis=0)
    if n == 1:
        return MeanCI(_plain(mean), _plain(np.zeros_like(mean)), None)
    sd = v.std(axis=0, ddof=1)
    return MeanCI(_plain(mean), _plain(sd), _plain(stats.t.ppf(0.5 + level / 2, n - 1) * sd / np.sqrt(n)))


def _plain(x):
    """A 0-d result as a Python float; arrays as they are."""
    return float(x) if np.ndim(x) == 0 else x


def seed_stats(values, level: float = CI_LEVEL) -> dict:
    """``n``, ``mean``, ``sd`` and the interval ``ci_lo``, ``ci_hi`` (``mean_ci``) of the
    finite scalars among ``values`` (``None``, NaN and infinities are left out): the form of
    a sweep's summary. Undefined numbers are NaN (no interval from fewer than two values)."""
    v = [float(x) for x in values if x is not None and math.isfinite(x)]
    st = mean_ci(v, level)
    half = math.nan if st.half is None else st.half
    return dict(n=len(v), mean=st.mean, sd=st.sd, ci_lo=st.mean - half, ci_hi=st.mean + half)


def first_crossing(x, y, level: float, *, above: bool = True) -> float:
    """The smallest ``x`` where ``y`` first reaches ``level`` (``y >= level`` if ``above``,
    else ``y < level``), interpolated between the grid points around the crossing: ``y``
    linear in ``log x`` between positive points, linear in ``x`` from ``x = 0``. NaN if it
    is never reached; ``x[0]`` if it is reached there. ``x`` ascending, ``(P,)``."""
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    hit = (y >= level) if above else (y < level)
    hit &= np.isfinite(y)
    if not hit.any():
        return math.nan
    k = int(np.argmax(hit))
    if k == 0:
        return float(x[0])
    x0, x1, y0, y1 = x[k - 1], x[k], y[k - 1], y[k]
    if not math.isfinite(y0) or y1 == y0:
        return float(x1)
    t = (level - y0) / (y1 - y0)
    if x0 > 0:
        return float(math.exp(math.log(x0) + t * (math.log(x1) - math.log(x0))))
    return float(x0 + t * (x1 - x0))


def bootstrap(values, statistic: Callable[[np.ndarray], np.ndarray], *, n_boot: int = 2000, seed: int = 0):
    """``statistic`` of ``n_boot`` resamples of ``values``' rows (axis 0: seeds, resampled whole
    with ``default_rng(seed)``), stacked: ``(n_boot, ...)``. The one bootstrap of the studies."""
    v = np.asarray(values)
    rng = np.random.default_rng(seed)
    s = v.shape[0]
    return np.array([statistic(v[rng.integers(0, s, s)]) for _ in range(n_boot)])


def bootstrap_crossing(
    x, values, level_fn: Callable[[np.ndarray], float], *, above: bool = True, n_boot: int = 2000, seed: int = 0
) -> dict:
    """The crossing of the seed-mean curve and its percentile bootstrap interval over seeds
    (``CI_LEVEL``).

    ``values`` ``(S, P)``: one curve per seed over the ascending grid ``x`` ``(P,)`` (NaN for
    a diverged trial, left out of the means). ``level_fn(mean curve)`` gives the level to
    cross (e.g. twice the curve's first value). Seeds are resampled whole (the grid points
    of one seed share its perturbation), ``n_boot`` times with a fixed PRNG. Resamples
    that never cross count as beyond the grid's end. Returns ``value`` (NaN: not reached),
    ``ci_lo``, ``ci_hi`` (``inf`` when more than 2.5% of the resamples do not cross),
    ``not_reached`` (fraction of resamples), ``seeds``.
    """
    v = np.asarray(values, dtype=float)
    x = np.asarray(x, dtype=float)

    def crossing(curves):
        with warnings.catch_warnings():  # a grid point where every resampled seed diverged: NaN
            warnings.simplefilter("ignore", RuntimeWarning)
            mean = np.nanmean(curves, axis=0)
        return first_crossing(x, mean, level_fn(mean), above=above)

    value = crossing(v)
    s = v.shape[0]
    boots = bootstrap(v, crossing, n_boot=n_boot, seed=seed) if s > 1 else np.array([value])
    boots = np.where(np.isnan(boots), np.inf, boots)
    q = [(1 - CI_LEVEL) / 2, 1 - (1 - CI_LEVEL) / 2]
    lo, hi = np.quantile(boots, q, method="inverted_cdf") if s > 1 else (math.nan, math.nan)
    return dict(value=value, ci_lo=float(lo), ci_hi=float(hi), not_reached=float(np.mean(np.isinf(boots))), seeds=s)
