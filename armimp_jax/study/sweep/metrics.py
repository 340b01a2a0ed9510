"""What a study keeps of one trial's estimate, and the one way every study scores it.

``ESTIMATE_FIELDS`` are the ``Estimate`` arrays a trial record holds (``estimate_arrays``
takes trial ``j`` of a batch's estimate). ``score`` is the one scorer of an estimate against
the arm's true impedance: accuracy, phase error, the coherence minima per band and per
output channel, the input coherence. The studies keep their own columns of it:
``trial_metrics`` (the reproduction's and the claim explanations'), ``trial_row`` (a sweep's
table row, with the fitted ``M, B, K``; the batch's own ``phi_T`` passed in).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from ..._estimation.metrics import largest_singular_value
from ..._model.arm import Arm
from .tables import ELEMENTS, METRIC_COLUMNS

ESTIMATE_FIELDS = ("f", "Z", "coh_multiple_x", "coh_partial_x", "coh_multiple_fh", "coh_partial_fh", "coh_inputs")
COHERENCES = ("coh_multiple_x", "coh_partial_x", "coh_multiple_fh", "coh_partial_fh")
LOW_BAND_HZ = 2.0  # the paper's "below 1-2 Hz"


def estimate_arrays(estimate, j: int) -> dict[str, np.ndarray]:
    """The ``ESTIMATE_FIELDS`` of trial ``j`` of a batch's ``Estimate`` (leading axis: trials)
    as NumPy arrays."""
    return {name: np.asarray(getattr(estimate, name)[j]) for name in ESTIMATE_FIELDS}


def score(f, Z, coherences, arm: Arm, *, accuracy=None, input_coherence=None, low_band: float = LOW_BAND_HZ) -> dict:
    """Every score of one estimate ``Z`` ``(F, 2, 2)`` [N/m] on bins ``f`` ``(F,)`` [Hz]
    against ``arm``'s impedance.

    ``phi_T`` [N/m]: the mean over bins of the largest singular value of the error;
    ``phi_ij`` (2, 2): the mean absolute error per entry (``accuracy``: these two as a batch
    computed them, else here); ``rel_error``: ``phi_T`` over the mean largest singular value
    of the truth; ``phase_error_deg``: the mean absolute phase error [deg] over the entries
    whose truth is not zero. ``coherences`` maps the ``COHERENCES`` and ``coh_inputs`` to arrays
    ``(F, 2)``; each coherence gives its minimum below and above ``low_band`` [Hz] (NaN where a
    band holds no bin) and its median; each multiple coherence its minimum and median per output
    channel (``coh_x1_min``, ...);
    ``coh_min`` the least of the multiple coherences (position and force); and
    ``input_coherence_max`` the largest input coherence (or ``input_coherence``, a batch's).
    """
    f = np.asarray(f)
    zt = np.asarray(arm.impedance(f))
    err = zt - Z
    if accuracy is None:
        phi_t, phi_ij = float(np.mean(np.asarray(largest_singular_value(err)))), np.mean(np.abs(err), axis=0)
    else:
        phi_t, phi_ij = float(accuracy[0]), np.asarray(accuracy[1])
    scale = float(np.mean(np.asarray(largest_singular_value(zt))))
    # an entry whose truth is zero (an arm without cross-coupling) has no phase to miss
    z, zt_b = np.asarray(Z), np.broadcast_to(zt, np.shape(Z))
    defined = np.abs(zt_b) > 0
    phase = np.degrees(np.abs(np.angle(z[defined] / zt_b[defined])))
    low, high = f < low_band, f >= low_band
    m = dict(phi_T=phi_t, phi_ij=np.asarray(phi_ij).tolist(), rel_error=phi_t / scale)
    m["phase_error_deg"] = float(np.mean(phase))
    for name in COHERENCES:
        c = np.asarray(coherences[name])
        m[f"{name}_min_low"] = float(c[low].min()) if low.any() else float("nan")
        m[f"{name}_min_high"] = float(c[high].min()) if high.any() else float("nan")
        m[f"{name}_median"] = float(np.median(c))
    cx, cf = np.asarray(coherences["coh_multiple_x"]), np.asarray(coherences["coh_multiple_fh"])
    m["coh_min"] = float(min(cx.min(), cf.min()))
    for name, c in (("x", cx), ("fh", cf)):
        for j in range(2):
            m[f"coh_{name}{j + 1}_min"] = float(c[:, j].min())
            m[f"coh_{name}{j + 1}_median"] = float(np.median(c[:, j]))
    given = np.max(coherences["coh_inputs"]) if input_coherence is None else input_coherence
    m["input_coherence_max"] = float(given)
    return m


REPRODUCTION_SCORES = (
    ("phi_T", "phi_ij", "rel_error", "phase_error_deg")
    + tuple(f"{name}_{part}" for name in COHERENCES for part in ("min_low", "min_high", "median"))
    + ("input_coherence_max",)
)


def trial_metrics(f, Z, coherences, arm: Arm, *, low_band: float = LOW_BAND_HZ) -> dict:
    """The reproduction's scores of one estimate (``score``'s ``REPRODUCTION_SCORES``): accuracy,
    phase error, each coherence's minimum below and above ``low_band`` and its median, the
    largest input coherence."""
    m = score(f, Z, coherences, arm, low_band=low_band)
    return {k: m[k] for k in REPRODUCTION_SCORES}


def _cells(prefix: str, a) -> dict:
    a = np.asarray(a, dtype=float).reshape(-1)
    return {f"{prefix}_{e}": float(v) for e, v in zip(ELEMENTS, a, strict=True)}


def trial_row(arm: Arm, outcome_i: Mapping, fit_i: Mapping) -> dict:
    """A sweep's table row of one trial of ``arm`` (``METRIC_COLUMNS`` plus ``diverged``,
    ``diverged_at``): ``score`` of its estimate with the batch's ``phi_T``, ``phi_ij`` and input
    coherence, and the fitted ``M, B, K`` with their SEs and VAF."""
    m = score(
        outcome_i["f"],
        outcome_i["Z"],
        outcome_i,
        arm,
        accuracy=(outcome_i["phi_T"], outcome_i["phi_ij"]),
        input_coherence=outcome_i["input_coherence"],
    )
    row = dict(m, **_cells("phi", m["phi_ij"]))
    for p, field in (("M", "mass"), ("B", "damping"), ("K", "stiffness")):
        row |= _cells(p, fit_i[field])
        row |= {k + "_se": v for k, v in _cells(p, fit_i[field + "_se"]).items()}
    row |= _cells("vaf", fit_i["vaf"])
    row["vaf_overall"] = float(fit_i["vaf_overall"])
    row = {k: row[k] for k in METRIC_COLUMNS}
    row["diverged"] = bool(outcome_i["diverged"])
    row["diverged_at"] = int(outcome_i["diverged_at"])
    return row
