"""What a study keeps of one trial's estimate, and the scores every study computes from it.

``ESTIMATE_FIELDS`` are the ``Estimate`` arrays a trial record holds (``estimate_arrays``
takes trial ``j`` of a batch's estimate); ``trial_metrics`` scores one estimate against the
arm's true impedance: accuracy, phase error and the coherence minima per band. The
reproduction, the claim explanations and their tests use these; a sweep's table row
(``study.sweep``) reads the batch's own ``phi_T`` and adds the fitted ``M, B, K``.
"""

from __future__ import annotations

import numpy as np

from .._estimation.metrics import largest_singular_value
from .._model.arm import Arm

ESTIMATE_FIELDS = ("f", "Z", "coh_multiple_x", "coh_partial_x", "coh_multiple_fh", "coh_partial_fh", "coh_inputs")
COHERENCES = ("coh_multiple_x", "coh_partial_x", "coh_multiple_fh", "coh_partial_fh")
LOW_BAND_HZ = 2.0  # the paper's "below 1-2 Hz"


def estimate_arrays(estimate, j: int) -> dict[str, np.ndarray]:
    """The ``ESTIMATE_FIELDS`` of trial ``j`` of a batch's ``Estimate`` (leading axis: trials)
    as NumPy arrays."""
    return {name: np.asarray(getattr(estimate, name)[j]) for name in ESTIMATE_FIELDS}


def trial_metrics(f, Z, coherences, arm: Arm, *, low_band: float = LOW_BAND_HZ) -> dict:
    """Scalar scores of one estimate ``Z`` ``(F, 2, 2)`` [N/m] on bins ``f`` ``(F,)`` [Hz]
    against ``arm``'s impedance.

    ``phi_T`` [N/m]: the mean over bins of the largest singular value of the error;
    ``phi_ij`` (2, 2): the mean absolute error per entry; ``rel_error``: ``phi_T`` over the
    mean largest singular value of the truth; ``phase_error_deg``: the mean absolute phase
    error [deg]. ``coherences`` maps the ``COHERENCES`` and ``coh_inputs`` to arrays ``(F, 2)``;
    each coherence gives its minimum below and above ``low_band`` [Hz] (NaN where a band
    holds no bin) and its median; ``input_coherence_max`` is the largest input coherence.
    """
    f = np.asarray(f)
    zt = np.asarray(arm.impedance(f))
    err = zt - Z
    phi_t = float(np.mean(np.asarray(largest_singular_value(err))))
    scale = float(np.mean(np.asarray(largest_singular_value(zt))))
    phase = np.degrees(np.abs(np.angle(Z / zt)))
    low, high = f < low_band, f >= low_band
    m = dict(
        phi_T=phi_t,
        phi_ij=np.mean(np.abs(err), axis=0).tolist(),
        rel_error=phi_t / scale,
        phase_error_deg=float(np.mean(phase)),
    )
    for name in COHERENCES:
        c = np.asarray(coherences[name])
        m[f"{name}_min_low"] = float(c[low].min()) if low.any() else float("nan")
        m[f"{name}_min_high"] = float(c[high].min()) if high.any() else float("nan")
        m[f"{name}_median"] = float(np.median(c))
    m["input_coherence_max"] = float(np.max(coherences["coh_inputs"]))
    return m
