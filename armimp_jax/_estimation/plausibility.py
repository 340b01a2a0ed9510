"""An implausible estimate's likely causes in a lab's terms: ``plausibility_warnings``, on the
rule of ``_model.plausibility`` (what a human arm can be), for a classical fit
(``fit_warnings``) and ``identify``'s answer alike. Host-side (NumPy).

An answer no human arm gives is rarely the arm; each usual cause moves M, B, K its own way:

- the force's sign: a sensor that reads the force the hand exerts on the handle gives
  ``-F_h``, which flips every matrix (on one axis: that axis' row), so M, B and K are all
  negative there;
- units: positions in mm read as m make M, B and K 1000 times too small, forces in mN 1000
  times too large;
- the sample rate: a rate given as ``r`` times the true one relabels every frequency ``f`` as
  ``r f``, so ``Z = K - w^2 M + j w B`` is fitted with ``M / r^2``, ``B / r`` and ``K``
  unchanged; given too low (``r < 1``), the classical fit also reads bins beyond the
  perturbation's band, where the estimate is noise, and its M and K go anywhere;
- noise, where every such value's 95% interval still reaches plausible values.
"""

from __future__ import annotations

import numpy as np

from .._model.plausibility import UNITS, Finding, findings

SIGN = (
    "the force's sign (a sensor that reads the force the hand exerts on the handle gives -F_h and flips every "
    "matrix: negate both fh columns, or that of the axis whose M, B and K are all negative)"
)
UNITS_OUT = (
    "units (positions in mm read as m make M, B and K 1000 times too small, in cm 100 times; forces in mN make "
    "them 1000 times too large)"
)
RATE = (
    "the sample rate (a rate given as r times the recording's true one gives M / r^2 and B / r with K "
    "unchanged, and given too low, fits bins beyond the perturbation's band, where the estimate is noise: "
    "check fs against the file's timestamps)"
)
NOISE = "noise (the 95% interval reaches plausible values: a longer record or a larger perturbation narrows it)"


def _flipped(matrices: dict) -> bool:
    """M, B and K are all given and all negative on the diagonal of some axis."""
    if any(matrices.get(m) is None for m in UNITS):
        return False
    diagonals = np.stack([np.diag(np.asarray(matrices[m], dtype=float)) for m in UNITS])
    return bool(np.any(np.all(diagonals < 0, axis=0)))


def likely_causes(found: list[Finding], matrices: dict) -> list[str]:
    """The causes of ``found`` (in ``matrices``), most likely first: noise where every entry's
    95% interval reaches plausible values; then the force's sign where M, B and K are all
    negative on an axis, units where a mass is out of range, else the sample rate; then the
    others."""
    if _flipped(matrices):
        order = [SIGN, UNITS_OUT, RATE]
    elif any(f.matrix == "mass" and f.why != "negative" for f in found):
        order = [UNITS_OUT, RATE, SIGN]
    else:
        order = [RATE, SIGN, UNITS_OUT]
    return ([NOISE] if all(f.reaches for f in found) else []) + order


def _symbol(matrix: str, axis: int) -> str:
    return f"{dict(mass='M', damping='B', stiffness='K')[matrix]}{'xy'[axis] * 2}"


def plausibility_warnings(
    matrices: dict, se: dict | None = None, *, classical: bool = False, label=None, beyond_noise: bool = False
) -> list[str]:
    """One warning naming every implausible diagonal entry of ``matrices`` (``{"mass": (2, 2),
    "damping": ..., "stiffness": ...}``; ``_model.plausibility.findings``, the classical rule
    with ``classical``) and its likely causes (``likely_causes``), or none. ``se``: their
    standard errors (optional); ``label(matrix, axis)`` names an entry (default ``Mxx``).
    ``beyond_noise``: none where every such entry's 95% interval reaches plausible values (a
    small stiffness estimated below zero within its interval is the interval's to tell)."""
    found = findings(matrices, se, classical=classical)
    if not found or (beyond_noise and all(f.reaches for f in found)):
        return []
    label = label or _symbol
    entries = ", ".join(f"{label(f.matrix, f.axis)} {f.value:.4g} {UNITS[f.matrix]} ({f.why})" for f in found)
    causes = "; ".join(likely_causes(found, matrices))
    return [f"implausible for a human arm: {entries}; likely causes, most likely first: {causes}"]
