"""Acceptance bands for the statistics tier (``pytest -m stats``): what a claimed coverage or
ratio of spreads allows a finite Monte Carlo to measure.

Every band is two-sided at ``ALPHA`` (a 99.9% band): a claim that holds fails its test with
probability at most 0.1% at a new set of seeds. Where the measurements are correlated (the
entries of one fit), the band uses the effective number of independent measurements implied by
their correlation (``effective_intervals``, ``effective_dof``), so it is neither too narrow
(correlated entries counted as independent) nor needlessly wide. docs/performance.md ("The
statistics tier") gives each band with the claim it checks and the measured value.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.stats

ALPHA = 1e-3  # two-sided: 99.9% bands
Z95 = float(scipy.stats.norm.ppf(0.975))


def coverage_band(n_eff: float, low: float, high: float, alpha: float = ALPHA) -> tuple[float, float]:
    """``(a, b)``: a pooled coverage measured on ``n_eff`` independent intervals lies within
    ``[a, b]`` with probability at least ``1 - alpha`` when the true coverage lies in
    ``[low, high]`` (the binomial's ``alpha / 2`` quantile at ``low`` and ``1 - alpha / 2``
    quantile at ``high``; ``n_eff`` rounded down, which widens the band)."""
    n = max(1, math.floor(n_eff))
    a = scipy.stats.binom.ppf(alpha / 2, n, low) / n
    b = scipy.stats.binom.ppf(1 - alpha / 2, n, high) / n
    return float(a), float(b)


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
    var = 0.0
    for i in range(k):
        for j in range(k):
            var += p * (1 - p) if i == j else _inside_both(float(corr[i, j]), z) - p * p
    return n_records * k * k * p * (1 - p) / var


def effective_dof(corr, n_records: int) -> float:
    """Satterthwaite degrees of freedom of the mean over ``k`` entries of ``s_e^2 / sigma_e^2``
    (each sample variance of ``n_records`` Gaussian values, errors correlated as ``corr``):
    ``(n - 1) k^2 / sum_ef corr_ef^2``; between ``n - 1`` (one entry) and ``k (n - 1)``."""
    corr = np.asarray(corr, dtype=float)
    k = corr.shape[0]
    return (n_records - 1) * k * k / float(np.sum(corr**2))


def ratio_band(low, high, dof: float, reference_dof: float | None = None, alpha: float = ALPHA):
    """``(a, b)`` for the RMS over entries of ``spread_e / reference_e`` when each true ratio lies
    in ``[low_e, high_e]``: ``a^2 = mean(low^2) q_lo``, ``b^2 = mean(high^2) q_hi`` with ``q`` the
    ``alpha / 2`` and ``1 - alpha / 2`` quantiles of ``chi2(dof) / dof``, or of ``F(dof,
    reference_dof)`` when the reference is itself a Monte Carlo estimate (``predict_se``'s draws)."""
    lo2 = float(np.mean(np.square(low)))
    hi2 = float(np.mean(np.square(high)))
    if reference_dof is None:
        q_lo = scipy.stats.chi2.ppf(alpha / 2, dof) / dof
        q_hi = scipy.stats.chi2.ppf(1 - alpha / 2, dof) / dof
    else:
        q_lo = scipy.stats.f.ppf(alpha / 2, dof, reference_dof)
        q_hi = scipy.stats.f.ppf(1 - alpha / 2, dof, reference_dof)
    return math.sqrt(lo2 * q_lo), math.sqrt(hi2 * q_hi)


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
