"""Acceptance bands for the statistics tier (``pytest -m stats``): what a claimed coverage, SD of
z or ratio of spreads allows a Monte Carlo of a given size to measure, and what it can tell.

A band is the region a true claim's measurement falls in with probability at least ``1 - alpha``
(``Band.false_alarm`` states the exact probability outside it: the binomial's for a coverage, the
chi-square's or F's for a spread). Every band is two-sided at ``ALPHA`` (99.9%); ``k`` entries
checked one by one share it (``ALPHA / k`` each). Where measurements are correlated (the
entries of one fit), the band uses the effective number of independent measurements implied by
their correlation (``effective_intervals``, ``effective_dof``).

A band is only as good as what it refuses. ``*_power`` gives the probability that a broken
variant (SEs, a bound or a prediction ``scale`` times the truth) falls outside the band;
``detectable_scale`` the smallest such factor refused either way with probability ``POWER``; and
``recordings_needed`` the Monte Carlo size at which a factor ``SCALE`` is. docs/performance.md
("The statistics tier") gives each claim's band and what it can resolve.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple

import numpy as np
import scipy.stats

ALPHA = 1e-3  # two-sided: 99.9% bands; the tier's ~50 of them together raise a false alarm ~5% of runs
Z95 = float(scipy.stats.norm.ppf(0.975))
POWER = 0.9  # a band "detects" a broken variant it refuses with this probability
SCALE = 1.2  # issue 65's broken variant: SEs, bounds, predictions 1.2 times off either way


class Band(NamedTuple):
    """``[low, high]``, and ``false_alarm``: the largest probability that a true claim's
    measurement falls outside it (at most the ``alpha`` it was made for)."""

    low: float
    high: float
    false_alarm: float

    def holds(self, value: float) -> bool:
        return bool(self.low <= value <= self.high)


def _binom_outside(n: int, p: float, a: float, b: float) -> float:
    """``P(X / n < a or X / n > b)`` for ``X ~ Binomial(n, p)``; the counts rounded as the band's."""
    lo, hi = round(a * n), round(b * n)
    return float(scipy.stats.binom.cdf(lo - 1, n, p) + scipy.stats.binom.sf(hi, n, p))


def coverage_band(n_eff: float, low: float, high: float | None = None, alpha: float = ALPHA) -> Band:
    """A pooled coverage measured on ``n_eff`` independent intervals, when the true coverage lies
    in ``[low, high]`` (``high`` defaults to ``low``: a point claim): the binomial's ``alpha / 2``
    quantile at ``low`` and ``1 - alpha / 2`` quantile at ``high``, ``n_eff`` rounded down (which
    widens the band)."""
    high = low if high is None else high
    n = max(1, math.floor(n_eff))
    a = scipy.stats.binom.ppf(alpha / 2, n, low) / n
    b = scipy.stats.binom.ppf(1 - alpha / 2, n, high) / n
    worst = max(_binom_outside(n, p, a, b) for p in (low, high))
    return Band(float(a), float(b), worst)


def sd_band(dof: float, low: float = 1.0, high: float | None = None, alpha: float = ALPHA, reference_dof=None) -> Band:
    """An RMS ratio (the SD of z about 0, or a spread over a reference) measured with ``dof``
    degrees of freedom, when the true ratio lies in ``[low, high]``: ``low sqrt(q_lo)``,
    ``high sqrt(q_hi)`` with ``q`` the ``alpha / 2`` and ``1 - alpha / 2`` quantiles of
    ``chi2(dof) / dof``, or of ``F(dof, reference_dof)`` when the reference is itself a Monte Carlo
    estimate with ``reference_dof`` (``predict_se``'s draws). Exact for Gaussian errors."""
    high = low if high is None else high
    q_lo, q_hi = _ratio_quantiles(dof, reference_dof, (alpha / 2, 1 - alpha / 2))
    return Band(low * math.sqrt(q_lo), high * math.sqrt(q_hi), alpha)


def _ratio_quantiles(dof, reference_dof, probabilities):
    if reference_dof is None:
        return [scipy.stats.chi2.ppf(p, dof) / dof for p in probabilities]
    return [scipy.stats.f.ppf(p, dof, reference_dof) for p in probabilities]


def ratio_band(low, high, dof: float, reference_dof: float | None = None, alpha: float = ALPHA) -> Band:
    """``sd_band`` for the RMS over entries of ``spread_e / reference_e`` when each true ratio lies
    in ``[low_e, high_e]``: the claim's RMS ends, ``sqrt(mean(low^2))`` and ``sqrt(mean(high^2))``."""
    lo = math.sqrt(float(np.mean(np.square(low))))
    hi = math.sqrt(float(np.mean(np.square(high))))
    return sd_band(dof, lo, hi, alpha, reference_dof)


def scaled_coverage(coverage: float, scale: float) -> float:
    """The coverage of normal intervals of true coverage ``coverage`` once their SEs are ``scale``
    times too large."""
    z = scipy.stats.norm.ppf(0.5 + coverage / 2)
    return float(2 * scipy.stats.norm.cdf(z * scale) - 1)


def coverage_power(band: Band, n_eff: float, scale: float, coverage: float = 0.95) -> float:
    """The probability that intervals of true coverage ``coverage`` with SEs ``scale`` times too
    large measure a pooled coverage outside ``band`` over ``n_eff`` independent intervals."""
    n = max(1, math.floor(n_eff))
    return _binom_outside(n, scaled_coverage(coverage, scale), band.low, band.high)


def sd_power(band: Band, dof: float, scale: float, ratio: float = 1.0, reference_dof=None) -> float:
    """The probability that an RMS ratio of true value ``ratio`` measures outside ``band`` once
    its denominator (the SEs, the bound, the prediction) is ``scale`` times too large: the
    measurement is ``ratio / scale`` times ``sqrt(chi2(dof) / dof)`` (or ``sqrt(F)``)."""
    m = ratio / scale
    if reference_dof is None:
        dist = scipy.stats.chi2(dof, scale=1 / dof)
    else:
        dist = scipy.stats.f(dof, reference_dof)
    return float(dist.cdf((band.low / m) ** 2) + dist.sf((band.high / m) ** 2))


def detectable_scale(power_of: Callable[[float], float], power: float = POWER, largest: float = 10.0) -> float:
    """The smallest factor ``s >= 1`` that ``power_of`` (a scale's probability of refusal) refuses
    with probability ``power`` both ways (``s`` and ``1 / s``); ``inf`` if not within ``largest``.
    Bisection in ``log s``: refusal grows with the distance from the truth either way."""

    def refused(s):
        return power_of(s) >= power and power_of(1 / s) >= power

    if not refused(largest):
        return math.inf
    lo, hi = 0.0, math.log(largest)
    while hi - lo > 1e-4:
        mid = (lo + hi) / 2
        lo, hi = (lo, mid) if refused(math.exp(mid)) else (mid, hi)
    return math.exp(hi)


def recordings_needed(
    power_at: Callable[[int, float], float], scale: float = SCALE, power: float = POWER, largest: int = 10**4
) -> float:
    """The smallest Monte Carlo size ``n`` at which ``power_at(n, s)`` (the refusal probability of
    a factor ``s`` off at size ``n``, its band made at ``n``) reaches ``power`` for ``scale`` and
    ``1 / scale``; ``inf`` if not within ``largest`` (an F band: the reference's own draws limit
    it). Bisection over ``n``; a binomial band's steps can make the power dip by a little just
    above the ``n`` returned."""

    def refused(n):
        return power_at(n, scale) >= power and power_at(n, 1 / scale) >= power

    if not refused(largest):
        return math.inf
    lo, hi = 2, largest
    while hi - lo > 1:
        mid = (lo + hi) // 2
        lo, hi = (lo, mid) if refused(mid) else (mid, hi)
    return hi


def _inside_both(rho: float, z: float) -> float:
    """``P(|X| < z, |Y| < z)`` for standard normals of correlation ``rho``."""
    if abs(rho) > 1 - 1e-9:
        return float(2 * scipy.stats.norm.cdf(z) - 1)
    mvn = scipy.stats.multivariate_normal(mean=[0.0, 0.0], cov=[[1.0, rho], [rho, 1.0]])
    return float(mvn.cdf([z, z]) - mvn.cdf([-z, z]) - mvn.cdf([z, -z]) + mvn.cdf([-z, -z]))


def effective_intervals(corr, n_records: int, coverage: float = 0.95) -> float:
    """The number of independent intervals whose binomial spread equals that of the pooled
    coverage of ``k`` correlated entries (error correlation ``corr``, ``(k, k)``) over
    ``n_records`` independent records: ``n k^2 p (1 - p) / Var(sum_e 1[entry e covers])``,
    the indicators' covariances from the bivariate normal (``k n`` when the entries are
    independent, ``n`` when they are one)."""
    corr = np.asarray(corr, dtype=float)
    k = corr.shape[0]
    z = float(scipy.stats.norm.ppf(0.5 + coverage / 2))
    p = coverage
    var = k * p * (1 - p)
    for i in range(k):
        for j in range(i + 1, k):  # symmetric; uncorrelated normals' indicators are independent
            var += 0.0 if corr[i, j] == 0 else 2 * (_inside_both(float(corr[i, j]), z) - p * p)
    return n_records * k * k * p * (1 - p) / var


def effective_dof(corr, n_records: int, ddof: int = 1) -> float:
    """Satterthwaite degrees of freedom of the mean over ``k`` entries of ``s_e^2 / sigma_e^2``
    (each a mean square of ``n_records`` Gaussian values, ``ddof`` of them spent on a mean; errors
    correlated as ``corr``): ``(n - ddof) k^2 / sum_ef corr_ef^2``; between ``n - ddof`` (one
    entry) and ``k (n - ddof)`` (independent entries)."""
    corr = np.asarray(corr, dtype=float)
    k = corr.shape[0]
    return (n_records - ddof) * k * k / float(np.sum(corr**2))


def entry_ratio_interval(ratio: float, n_records: int, alpha: float) -> tuple[float, float]:
    """The ``1 - alpha`` interval of a true ratio ``sigma / reference`` from one entry's measured
    ``spread / reference`` over ``n_records`` Gaussian values (chi-square, ``n - 1`` dof)."""
    dof = n_records - 1
    return (
        ratio * math.sqrt(dof / scipy.stats.chi2.ppf(1 - alpha / 2, dof)),
        ratio * math.sqrt(dof / scipy.stats.chi2.ppf(alpha / 2, dof)),
    )


def correlation(samples) -> np.ndarray:
    """The correlation matrix of ``samples`` ``(n, k)`` (rows: records; columns: entries)."""
    return np.atleast_2d(np.corrcoef(np.asarray(samples, dtype=float), rowvar=False))
