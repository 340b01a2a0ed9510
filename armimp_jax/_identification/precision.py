"""How long to record for a precision: the two-sided normal quantile, the one formula of every
record length in the package (``record_seconds``: standard errors fall as one over the square
root of the record length), and the check of a precision and a level."""

from __future__ import annotations

import jax
import numpy as np

Z95 = 1.959963984540054  # scipy.stats.norm.ppf(0.975): the two-sided 95% normal quantile


def check_precision(precision, level: float = 0.95, *, where: str = "record_seconds") -> None:
    """One-line ``ValueError`` for a precision (a relative half-width) or a level outside (0, 1)."""
    if isinstance(precision, bool) or not (isinstance(precision, (int, float, np.floating)) and 0 < precision < 1):
        raise ValueError(
            f"{where}: precision must lie in (0, 1) (a relative half-width: 0.1 is +-10%), got {precision!r}"
        )
    if isinstance(level, bool) or not (isinstance(level, (int, float, np.floating)) and 0 < level < 1):
        raise ValueError(f"{where}: level must lie in (0, 1) (0.95: 95% intervals), got {level!r}")


def quantile(level: float = 0.95) -> float:
    """The two-sided normal quantile of ``level``: an interval ``+- quantile(level) SE``."""
    return Z95 if level == 0.95 else float(jax.scipy.stats.norm.ppf(0.5 + level / 2))


def record_seconds(
    seconds: float, relative_se: float, precision: float, *, level: float = 0.95, where: str = "record_seconds"
) -> float:
    """Seconds of recording for ``+- precision`` (relative half-width) at ``level`` on an entry
    whose relative standard error is ``relative_se`` at a record of ``seconds`` [s]: standard
    errors fall as one over the square root of the record length when the perturbation goes
    on with the same statistics. The one formula of every record length in the package
    (``record_for``'s three, a design's, the benchmarks': ``record_minutes``); a one-line
    ``ValueError`` for a precision or a level outside (0, 1)."""
    check_precision(precision, level, where=where)
    return seconds * (quantile(level) * relative_se / precision) ** 2


def record_minutes(seconds: float, relative_se: float, precision: float, *, level: float = 0.95) -> float:
    """``record_seconds`` in minutes."""
    return record_seconds(seconds, relative_se, precision, level=level, where="record_minutes") / 60
