"""What a human arm can be: the one rule behind the plausibility warnings on an arm a trial is
built with (``make_trial``), on a classical fit (``fit_warnings``) and on ``identify``'s answer
(``_estimation.plausibility`` words the causes of an implausible estimate). Host-side (NumPy),
on concrete values.

A human arm's endpoint mass diagonal lies well inside ``MASS_RANGE`` (the paper's four arms:
0.49-2.24 kg), and its damping and stiffness diagonals are positive (``F_h = M xdd + B xd +
K (x - x0)`` is the force on the hand). A classical fit's M and B also absorb the record's
timing (a fitted delay trades M for B; friction biases M low), so for it only negative M and
K diagonals count.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

MASS_RANGE = (0.05, 10.0)  # [kg] a human arm's endpoint mass diagonal
UNITS = {"mass": "kg", "damping": "N s/m", "stiffness": "N/m"}
Z95 = 1.959963984540054  # the two-sided 95% normal quantile

UNITS_IN = "units (a mass typed in grams is 1000 times too large: M_h is in kg)"
SIGN_IN = (
    "a sign convention (Arm's matrices give the force ON the hand, F_h = M xdd + B xd + K (x - x0), whose "
    "diagonals are positive for a human arm; a stiffness measured as the force the hand exerts has the "
    "opposite sign)"
)


class Finding(NamedTuple):
    """One implausible diagonal entry: its ``matrix`` (``"mass"``, ``"damping"``,
    ``"stiffness"``), ``axis`` (0: x, 1: y), ``value`` (in ``UNITS``), ``why`` (``"negative"``,
    ``"over 10 kg"``, ``"under 0.05 kg"``) and whether its 95% interval reaches plausible
    values (``reaches``; False where no SE was given)."""

    matrix: str
    axis: int
    value: float
    why: str
    reaches: bool


def _why(matrix: str, v: float, classical: bool) -> str | None:
    low, high = MASS_RANGE
    if matrix == "mass" and not classical and not low <= v <= high:
        return f"over {high:g} kg" if v > high else f"under {low:g} kg"
    if v < 0 and (matrix != "damping" or not classical):
        return "negative"
    return None


def _reaches(matrix: str, v: float, se: float, classical: bool) -> bool:
    if not (np.isfinite(se) and se > 0):
        return False
    return _why(matrix, v - Z95 * se, classical) is None or _why(matrix, v + Z95 * se, classical) is None


def findings(matrices: dict, se: dict | None = None, *, classical: bool = False) -> list[Finding]:
    """The implausible diagonal entries of ``matrices`` (``{"mass": (2, 2), ...}``; a matrix
    missing or ``None`` is not checked), with ``se`` (the same keys; optional) for whether each
    95% interval reaches plausible values. ``classical``: a classical fit's rule (negative M or
    K diagonals); otherwise a mass diagonal outside ``MASS_RANGE`` and a negative damping or
    stiffness diagonal."""
    out = []
    for matrix in UNITS:
        if matrices.get(matrix) is None:
            continue
        values = np.diag(np.asarray(matrices[matrix], dtype=float))
        given = se is not None and se.get(matrix) is not None
        errors = np.diag(np.asarray(se[matrix], dtype=float)) if given else np.full(2, np.nan)
        for axis in range(2):
            v = float(values[axis])
            why = _why(matrix, v, classical)
            if why is not None:
                out.append(Finding(matrix, axis, v, why, _reaches(matrix, v, float(errors[axis]), classical)))
    return out


def arm_input_warning(mass, damping, stiffness, *, where: str) -> list[str]:
    """A one-line warning for an arm a model is built with (concrete values): a mass diagonal
    outside ``MASS_RANGE`` or a negative damping or stiffness diagonal, with the likely cause (a
    mass in grams, a sign convention); none for an all-zero arm (``no_arm``: the robot alone)."""
    matrices = dict(mass=mass, damping=damping, stiffness=stiffness)
    if not any(np.any(np.asarray(m) != 0) for m in matrices.values()):
        return []
    found = findings(matrices)
    if not found:
        return []
    entries = ", ".join(f"{f.matrix}[{f.axis},{f.axis}] {f.value:.4g} {UNITS[f.matrix]} ({f.why})" for f in found)
    causes = [UNITS_IN] * any(f.matrix == "mass" for f in found) + [SIGN_IN] * any(f.matrix != "mass" for f in found)
    return [f"{where}: an arm no human has: {entries}; likely cause: {'; '.join(causes)}"]
