"""The statistics tier's acceptance bands (tests/acceptance.py) do what they say, checked by plain
NumPy Monte Carlo (fast), and ``pytest -m stats`` selects the tier that the default run leaves out."""

import pathlib
import subprocess
import sys

import numpy as np
import pytest
import scipy.stats
from acceptance import (
    ALPHA,
    Z95,
    coverage_band,
    effective_dof,
    effective_intervals,
    entry_ratio_interval,
    ratio_band,
)

ROOT = pathlib.Path(__file__).resolve().parents[1]
RUNS = 2000
# misses a band of level 1 - ALPHA may make in RUNS runs of a true claim (a 1e-4 chance to exceed)
ALLOWED = int(scipy.stats.binom.ppf(1 - 1e-4, RUNS, ALPHA))


def _correlated_normals(rng, corr, n):
    return rng.standard_normal((n, corr.shape[0])) @ np.linalg.cholesky(corr).T


def test_the_coverage_band_holds_a_true_coverage_and_refuses_ses_1_5_times_off():
    """Records of 12 entries correlated as an arm fit's M and K (0.6), 50 records: a coverage of
    0.95 falls outside its band about 0.1% of the time (measured: 1 of 2000 runs), while SEs 1.5
    times too small or too large fail in every run."""
    rng = np.random.default_rng(1)
    corr = np.eye(12)
    for i in range(4):
        corr[i, i + 8] = corr[i + 8, i] = 0.6
    n = 50
    band = coverage_band(effective_intervals(corr, n), 0.95, 0.95)
    counts = {1.0: 0, 1 / 1.5: 0, 1.5: 0}
    for _ in range(RUNS):
        z = _correlated_normals(rng, corr, n)
        for scale in counts:
            coverage = np.mean(np.abs(z) <= Z95 * scale)
            counts[scale] += not band[0] <= coverage <= band[1]
    assert counts[1.0] <= ALLOWED and counts[1 / 1.5] == counts[1.5] == RUNS, (counts, band)


def test_effective_counts_span_independent_to_identical_entries():
    assert effective_intervals(np.eye(6), 50) == pytest.approx(300)
    assert effective_intervals(np.ones((6, 6)), 50) == pytest.approx(50, rel=1e-6)
    assert effective_dof(np.eye(6), 50) == pytest.approx(6 * 49)
    assert effective_dof(np.ones((6, 6)), 50) == pytest.approx(49)


def test_the_ratio_band_holds_a_true_ratio_and_refuses_1_5_times_off():
    """Six entries, two pairs correlated 0.6, 50 records: the RMS of spread / reference leaves the
    band of a true ratio 1 about 0.1% of the time (measured: 4 of 2000 runs), and leaves it in
    every run when the reference is 1.5 times too large or too small; an entry's own 99%
    chi-square interval holds its ratio."""
    rng = np.random.default_rng(2)
    corr = np.eye(6)
    corr[0, 4] = corr[4, 0] = corr[1, 5] = corr[5, 1] = 0.6
    n = 50
    dof = effective_dof(corr, n)
    band = ratio_band([1.0] * 6, [1.0] * 6, dof)
    misses = {1.0: 0, 1.5: 0, 1 / 1.5: 0}
    held = 0
    for _ in range(RUNS):
        spread = _correlated_normals(rng, corr, n).std(axis=0, ddof=1)
        for scale in misses:
            rms = np.sqrt(np.mean((spread / scale) ** 2))
            misses[scale] += not band[0] <= rms <= band[1]
        low, high = entry_ratio_interval(float(spread[0]), n, 0.01)
        held += low <= 1.0 <= high
    assert misses[1.0] <= ALLOWED and misses[1.5] == misses[1 / 1.5] == RUNS, (misses, band)
    assert held >= scipy.stats.binom.ppf(1e-4, RUNS, 0.99), held


def test_the_stats_tier_runs_only_when_asked():
    """``addopts`` leaves ``stats`` out of the default run; ``-m stats`` on the command line
    replaces it (pytest keeps the last ``-m``)."""

    def collected(*args):
        proc = subprocess.run(
            [sys.executable, "-m", "pytest", "--collect-only", "-q", "-p", "no:cacheprovider", *args],
            capture_output=True,
            text=True,
            cwd=ROOT,
            timeout=300,
        )
        return proc.stdout

    target = "tests/test_claims_numerics.py"
    assert "no tests collected (2 deselected)" in collected(target)
    assert "2 tests collected" in collected(target, "-m", "stats")
