"""Shared by the statistics tier's files (``tests/test_claims_*.py``): the identification
benchmarks' noise and truths, figures reported beside every assertion, and the summaries of a
Monte Carlo that the assertions read."""

from __future__ import annotations

import json
import os
import pathlib

import numpy as np
import scipy.stats
import validation
from acceptance import (
    ALPHA,
    SCALE,
    Z95,
    coverage_band,
    coverage_power,
    detectable_scale,
    effective_dof,
    effective_intervals,
    recordings_needed,
    sd_band,
    sd_power,
)

ARM = ("arm.mass", "arm.damping", "arm.stiffness")
DIAGONAL = tuple(f"{n}[{i},{i}]" for n in ARM for i in (0, 1))


def noise(aj, voluntary: float = 0.3) -> dict:
    """``make_trial``'s noise in the identification benchmarks (docs/identification.md section 6):
    force noise 0.05 N, 2^18-count encoders, the person's force ``voluntary`` N RMS below 2 Hz."""
    return dict(sensors=aj.Sensors(force_noise=0.05, encoder_counts=2**18), voluntary=aj.VoluntaryForce(voluntary, 2.0))


def entries(values: dict) -> dict:
    """``{label: value}`` of every entry of ``{name: array}`` (``arm.mass[0,1]``, ...)."""
    out = {}
    for name, v in values.items():
        v = np.asarray(v)
        for index in np.ndindex(v.shape):
            out[f"{name}[{','.join(map(str, index))}]"] = float(v[index])
    return out


def truth_entries(trial, names=ARM) -> dict:
    return entries({n: np.asarray(getattr(getattr(trial, n.split(".")[0]), n.split(".")[1])) for n in names})


def progress(text: str) -> None:
    """A line in ``ARMIMP_STATS_OUT/progress.log`` (when set): where a long Monte Carlo stands."""
    folder = os.environ.get("ARMIMP_STATS_OUT")
    if folder:
        pathlib.Path(folder).mkdir(parents=True, exist_ok=True)
        with open(pathlib.Path(folder) / "progress.log", "a") as f:
            f.write(text + "\n")


def report(name: str, figures: dict, raw: dict | None = None) -> None:
    """Print ``figures`` (seen with ``-s`` and in a failure's captured output) and write them as
    ``NAME.json`` in the tier's figures folder (``validation.figures_folder``), with ``raw`` (the
    Monte Carlo's own numbers) and the measuring run beside them: what docs/validation.md, the
    report the session writes at its end, shows."""
    text = json.dumps(figures, indent=1, default=float)
    print(f"\n[{name}]\n{text}")
    path = validation.figures_folder()
    path.mkdir(parents=True, exist_ok=True)
    saved = dict(figures, raw={k: np.asarray(v).tolist() for k, v in (raw or {}).items()}, run=validation.run_stamp())
    (path / f"{name}.json").write_text(json.dumps(saved, indent=1, default=float) + "\n")


# The precision the docs may print for what the tier holds: the smallest factor on the SEs (a
# bound, a prediction) its bands refuse either way with power 0.9 at 50 recordings. Measured with
# the entry cells' base-case correlation (tests/acceptance.py's functions on it): pooled over 12
# entries 1.20, over 6 diagonals 1.26 (1.29 against predict_se's 256 draws), one entry 1.74-1.83.
# Each test asserts its own run's resolution is no coarser, so a run whose entries correlate more
# says so instead of printing a precision it does not hold.
RESOLVES = dict(entries=1.3, diagonals=1.35, entry=1.9)
# What a lab can read in a failed fit's message: the search's advice (what to change) or the joints
# that stood still (``identify``'s diagnosis). A failure that says neither is a miss.
LAB_TERMS = ("record longer or with a larger perturbation", "stood still")
# Issue 61's claim on convergence: at least 98% of fits converge (the rest say why).
CONVERGED = 0.98


def explained(message: str) -> bool:
    """Whether a failed fit's ``message`` says why in a lab's terms (``LAB_TERMS``)."""
    return any(term in message for term in LAB_TERMS)


def convergence(messages, converged) -> dict:
    """Fits that failed, split by whether their message says why in a lab's terms: ``unexplained``
    (to be counted as misses) and ``explained`` (counted apart), and the binomial band on the
    failures of a claim of ``CONVERGED``: at most ``allowed`` of ``fits`` fail with probability
    ``1 - ALPHA``."""
    failed = [m for m, c in zip(messages, converged, strict=True) if not c]
    fits = len(failed) + sum(bool(c) for c in converged)
    allowed = int(scipy.stats.binom.ppf(1 - ALPHA, fits, 1 - CONVERGED))
    unexplained = [m for m in failed if not explained(m)]
    return dict(
        fits=fits,
        failed=len(failed),
        explained=len(failed) - len(unexplained),
        unexplained=unexplained,
        allowed=allowed,
    )


def calibration_check(z, unexplained: int = 0, nominal: float = 0.95, alpha: float = ALPHA) -> dict:
    """The intervals' calibration from ``z = (estimate - truth) / SE`` ``(n, k)`` (rows: converged
    fits), ``unexplained`` failed fits counted as records whose every interval missed. Pooled: the
    coverage of ``|z| <= Z95`` (binomial band at the entries' effective number of intervals) and the
    RMS of z (chi-square band at their effective dof, about the truth: a bias counts). Per entry:
    the same at ``alpha / k``. ``outside``: every figure outside its band."""
    z = np.asarray(z, dtype=float)
    n, k = z.shape
    hits = np.concatenate([np.abs(z) <= Z95, np.zeros((unexplained, k), bool)])
    corr = np.atleast_2d(np.corrcoef(z, rowvar=False))
    n_eff, dof = effective_intervals(corr, n + unexplained, nominal), effective_dof(corr, n, ddof=0)
    coverage, rms = float(hits.mean()), float(np.sqrt(np.mean(z**2)))
    entry_cov, entry_rms = hits.mean(axis=0), np.sqrt(np.mean(z**2, axis=0))
    bands = dict(
        coverage=coverage_band(n_eff, nominal, alpha=alpha),
        rms_z=sd_band(dof, alpha=alpha),
        entry_coverage=coverage_band(n + unexplained, nominal, alpha=alpha / k),
        entry_rms_z=sd_band(n, alpha=alpha / k),
    )
    outside = [("coverage", coverage)] * (not bands["coverage"].holds(coverage))
    outside += [("rms_z", rms)] * (not bands["rms_z"].holds(rms))
    outside += [(f"coverage[{e}]", float(c)) for e, c in enumerate(entry_cov) if not bands["entry_coverage"].holds(c)]
    outside += [(f"rms_z[{e}]", float(r)) for e, r in enumerate(entry_rms) if not bands["entry_rms_z"].holds(r)]
    figures = dict(coverage=coverage, rms_z=rms, effective_intervals=n_eff, dof=dof, records=n, unexplained=unexplained)
    figures.update(per_entry_coverage=entry_cov.tolist(), per_entry_rms_z=entry_rms.tolist(), bands=bands)
    figures["resolution"] = calibration_resolution(bands, n_eff, dof, n, nominal)
    return dict(figures, outside=outside)


def calibration_resolution(bands, n_eff, dof, n, nominal=0.95) -> dict:
    """The smallest factor on the SEs each of ``calibration_check``'s bands refuses either way
    with probability ``POWER``, and the records each would need to refuse ``SCALE``."""
    per_record = dof / n

    def pooled_z(m, s):
        return sd_power(sd_band(per_record * m), per_record * m, s)

    def entry_z(m, s):
        return sd_power(sd_band(m, alpha=bands["entry_rms_z"].false_alarm), m, s)

    return dict(
        coverage=detectable_scale(lambda s: coverage_power(bands["coverage"], n_eff, s, nominal)),
        rms_z=detectable_scale(lambda s: sd_power(bands["rms_z"], dof, s)),
        entry_rms_z=detectable_scale(lambda s: entry_z(n, s)),
        records_for_scale=dict(scale=SCALE, rms_z=recordings_needed(pooled_z), entry_rms_z=recordings_needed(entry_z)),
    )


def ratio_check(spread, reference, claims, n_records, corr, reference_dof=None, alpha=ALPHA) -> dict:
    """``spread / reference`` per entry over its claimed value (``claims``, one number per entry):
    their RMS against ``sd_band`` of a true 1 at the entries' effective dof (``corr``: the
    estimates' correlation), and each entry against its own band at ``alpha / k`` (``n - 1`` dof),
    or F bands where the reference is a Monte Carlo estimate with ``reference_dof``. ``outside``:
    every figure outside its band; ``resolution``: the smallest factor on the reference each band
    refuses with probability ``POWER``, and the records each needs to refuse ``SCALE``."""
    ratio = np.asarray(spread) / np.asarray(reference)
    normalized = ratio / np.asarray(claims, dtype=float)
    k = len(ratio)
    dof = effective_dof(corr, n_records)
    ref_dof = None if reference_dof is None else reference_dof * dof / (n_records - 1)
    rms = float(np.sqrt(np.mean(normalized**2)))
    band = sd_band(dof, alpha=alpha, reference_dof=ref_dof)
    entry_band = sd_band(n_records - 1, alpha=alpha / k, reference_dof=reference_dof)
    outside = [("rms", rms)] * (not band.holds(rms))
    outside += [(f"entry[{e}]", float(r)) for e, r in enumerate(normalized) if not entry_band.holds(r)]
    per_record = dof / (n_records - 1)

    def pooled(m, s):
        d = per_record * (m - 1)
        r = None if reference_dof is None else reference_dof * per_record
        return sd_power(sd_band(d, alpha=alpha, reference_dof=r), d, s, reference_dof=r)

    def entry(m, s):
        return sd_power(
            sd_band(m - 1, alpha=alpha / k, reference_dof=reference_dof), m - 1, s, reference_dof=reference_dof
        )

    resolution = dict(
        rms=detectable_scale(lambda s: sd_power(band, dof, s, reference_dof=ref_dof)),
        entry=detectable_scale(lambda s: entry(n_records, s)),
        records_for_scale=dict(scale=SCALE, rms=recordings_needed(pooled), entry=recordings_needed(entry)),
    )
    figures = dict(ratio=ratio.tolist(), claims=list(claims), rms=rms, dof=dof, band=band, entry_band=entry_band)
    return dict(figures, resolution=resolution, outside=outside)


def diagonal_z(rows, names=ARM) -> np.ndarray:
    """``z = (estimate - truth) / SE`` ``(n, 2 len(names))`` of the diagonals of ``names`` over the
    converged rows of ``armimp_bench.protocol.one`` (its ``values``, ``se``, ``truth``)."""
    ok = [r for r in rows if r["converged"] and not r["diverged"]]

    def diag(r, key, n):
        return np.diagonal(np.asarray(r[key][n], dtype=float))

    return np.array(
        [np.concatenate([(diag(r, "values", n) - diag(r, "truth", n)) / diag(r, "se", n) for n in names]) for r in ok]
    )
