"""Number formats shared by the claims' texts and the report: one place decides how a
number reads, so a value never prints as something it is not.

``short`` is the rule for quantities bounded by 1 and for those judged against a threshold:
a value under 1 in magnitude (a coherence of 0.9996) gets the digits it needs not to read
as 1, because "1.000" of a coherence says "perfect" where the estimate is not.
"""

from __future__ import annotations

import math
import re

DASH = "—"  # a missing value: a condition whose every trial diverged, or no interval
MAX_DIGITS = 9  # decimals ``short`` may add before it gives up (|x| within 5e-10 of 1)


def short(x, spec: str = ".3g") -> str:
    """``x`` in the format ``spec`` (``".3g"``, ``".2f"``...); where that rounds a value with
    ``|x| < 1`` to ``|1|``, with as many decimals (one more than ``spec``'s precision, up to
    ``MAX_DIGITS``) as it takes to stay under 1."""
    text = format(x, spec)
    if not (math.isfinite(x) and abs(x) < 1 and abs(float(text)) >= 1):
        return text
    precision = re.search(r"\.(\d+)", spec)
    for digits in range(int(precision.group(1)) + 1 if precision else 1, MAX_DIGITS + 1):
        text = format(x, f".{digits}f")
        if abs(float(text)) < 1:
            break
    return text


def num(x, spec: str = ".0f", fmt=format) -> str:
    """``fmt(x, spec)`` (``format``, or ``short`` for quantities bounded by 1), or ``—`` for
    ``None``."""
    return DASH if x is None else fmt(x, spec)


def mean_pm(mean, half, spec: str = ".0f", fmt=format) -> str:
    """``"mean ± half"`` (``half``: the 95% t-interval's half-width; ``None``: one seed, the
    mean alone), or ``—`` for a missing mean; the mean in ``fmt`` (as ``num``)."""
    if mean is None:
        return DASH
    return num(mean, spec, fmt) if half is None else f"{num(mean, spec, fmt)} ± {format(half, spec)}"


def times(k, x):
    """``k * x``, ``None`` kept."""
    return None if x is None else k * x


def interval(lo, hi, spec: str = ".3g") -> str:
    """``"[lo, hi]"`` of a 95% t-interval."""
    return f"[{short(lo, spec)}, {short(hi, spec)}]"
