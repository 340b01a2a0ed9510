"""Shared by the statistics tier's files (``tests/test_claims_*.py``): the identification
benchmarks' noise and truths, figures reported beside every assertion, and the summaries of a
Monte Carlo that the assertions read."""

from __future__ import annotations

import json
import os
import pathlib

import numpy as np
from acceptance import ALPHA, effective_dof, entry_ratio_interval, ratio_band

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
    """Print ``figures`` (seen with ``-s`` and in a failure's captured output) and, when
    ``ARMIMP_STATS_OUT`` names a folder, write them there as ``NAME.json`` (with ``raw``, the
    Monte Carlo's own numbers, beside them): the numbers docs/performance.md cites."""
    text = json.dumps(figures, indent=1, default=float)
    print(f"\n[{name}]\n{text}")
    folder = os.environ.get("ARMIMP_STATS_OUT")
    if folder:
        path = pathlib.Path(folder)
        path.mkdir(parents=True, exist_ok=True)
        saved = dict(figures, raw={k: np.asarray(v).tolist() for k, v in (raw or {}).items()})
        (path / f"{name}.json").write_text(json.dumps(saved, indent=1, default=float) + "\n")


def ratio_check(spread, reference, claims, n_records, corr, reference_dof=None, per_entry=True, pooled=None):
    """``spread / reference`` per entry, their RMS against ``ratio_band`` for the claimed
    ``(low, high)`` of each entry (or ``pooled``, a claim on the RMS itself), and (``per_entry``)
    each entry's own chi-square interval (``ALPHA / k``) against its claim: ``entries_outside``
    lists those that miss it."""
    ratio = spread / reference
    low, high = np.array([c[0] for c in claims]), np.array([c[1] for c in claims])
    dof = effective_dof(corr, n_records)
    ref_dof = None if reference_dof is None else reference_dof * dof / (n_records - 1)
    rms = float(np.sqrt(np.mean(ratio**2)))
    band = ratio_band(low, high, dof, ref_dof) if pooled is None else ratio_band([pooled[0]], [pooled[1]], dof, ref_dof)
    lonely = []
    for r, lo, hi in zip(ratio, low, high, strict=True) if per_entry else ():
        a, b = entry_ratio_interval(float(r), n_records, ALPHA / len(ratio))
        if b < lo or a > hi:
            lonely.append((float(r), (a, b), (float(lo), float(hi))))
    return dict(ratio=ratio.tolist(), rms=rms, band=band, dof=dof, entries_outside=lonely)
