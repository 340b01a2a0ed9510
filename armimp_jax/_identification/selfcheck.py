"""``identify``'s check of its own answer against the classical fit (``cross_check``).

The search matches the efficient statistic, exactly as many numbers as parameters, so it
always finds a root, and its covariance is the linearisation's there. Where the loop bends
(friction) a root can sit far from the truth while its intervals look tight. The classical fit
(``auxiliary.arm_statistics``: Welch, 1 Hz bins) is a second, independent summary of the same
recording. The closed-loop model at the answer predicts what it should read: the mean over
recordings simulated there, friction and sampling bias included. The two must agree within
their combined uncertainty, which the same simulated recordings give: for each of them, its
classical fit's deviation less the deviation of its own linearised re-estimate (the answer's
sensitivity to the efficient statistic), the two estimators' difference with their correlation
(a Hausman comparison by simulation). An entry outside that uncertainty is named, with both
values, and the answer's intervals are not to be trusted (``result.py``). Measured in
docs/identification.md section 6c.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import jax
import numpy as np
import scipy.stats

from . import indirect, search
from . import layout as lay
from .auxiliary import statistics

# Draws at the answer behind the check (the final binding's first ones, paired by their keys).
CHECK_DRAWS = 32
# The check's false-alarm rate over a recording's arm entries (Bonferroni over the entries), where
# the model explains the recording. At 0.01 (a bound of 3.70 for 12 entries on 32 draws) it named 2
# of the first 40 recordings at the truth, at z 3.86 and 3.94 (the difference's tails are heavier
# than the t model's), while the failure it is for stood at 5.7: 0.001 (4.53).
FALSE_ALARM = 0.001


class Disagreement(NamedTuple):
    """An arm entry where the classical fit and ``identify``'s answer disagree: the recording's
    classical value, what recordings simulated at the answer give for it, and their difference
    in combined standard errors (``z``)."""

    label: str
    classical: float
    predicted: float
    combined_se: float
    z: float


@functools.partial(jax.jit, static_argnames="layout")
def _classical_statistics(layout, model, f, x, fh):
    return statistics(layout, model, f, x, fh, None)


def arm_only(layout: lay.Layout) -> lay.Layout | None:
    """The layout's arm matrices alone, in its order (``None`` without them)."""
    kept = [(n, s) for n, s in zip(layout.names, layout.symmetric, strict=True) if n in lay.ARM_PARAMETERS]
    return lay.Layout(*map(tuple, zip(*kept))) if kept else None


def check_draws(n_draws: int) -> int:
    """``CHECK_DRAWS``, a multiple of the local devices, at most ``n_draws``."""
    n_dev = jax.local_device_count()
    return int(min(n_draws, math.ceil(CHECK_DRAWS / n_dev) * n_dev))


def threshold(k: int, entries: int) -> float:
    """The two-sided Bonferroni bound on ``entries`` z's at ``FALSE_ALARM``, each with ``k - 1``
    degrees of freedom (its variance from ``k`` draws)."""
    return float(scipy.stats.t.ppf(1.0 - FALSE_ALARM / (2 * entries), k - 1))


def cross_check(problem, p, stats, sens, recorded, labels) -> tuple[list[Disagreement], int]:
    """``(disagreements, dropped)``: the arm entries of every part where the recordings' classical
    fit departs from the model's at ``p`` by more than ``threshold`` combined SEs, and the
    simulated recordings left out for diverging (a part with fewer than 3 sound is not checked).

    ``stats`` ``(R, m)``: the efficient statistics of the binding at ``p`` (every part's, then
    the prior's moments), ``sens`` ``(n, m)`` the answer's sensitivity to them, ``recorded`` per
    recording ``(part, x, fh)``, ``labels`` the names of ``p``'s entries. The nuisance prior's
    moments (constant over the draws) add their variance, ``PRIOR_SD^2``, through ``sens``."""
    out, dropped = [], 0
    m = stats.shape[1] - problem.prior_index.size
    for t, part in enumerate(problem.parts):
        welch = arm_only(part.layout)
        if welch is None:
            continue
        k = check_draws(stats.shape[0])
        q = part.index[part.layout.index(lay.ARM_PARAMETERS)]  # the part's arm entries in p
        sim, diverged = indirect.binding_draws(
            part.layout, part.model, p[part.index], part.f, part.keys[:k], problem.numerics, None, welch
        )
        sim, ok = np.asarray(sim), ~np.asarray(diverged) & np.all(np.isfinite(np.asarray(sim)), axis=1)
        dropped += int(k - ok.sum())
        if ok.sum() < 3:
            continue
        own = [np.asarray(_classical_statistics(welch, part.model, part.f, x, fh)) for i, x, fh in recorded if i == t]
        efficient = stats[:k][ok] - stats.mean(axis=0)
        diff = (sim[ok] - sim[ok].mean(axis=0)) - efficient @ sens[q].T
        prior = search.PRIOR_SD**2 * np.sum(sens[q, m:] ** 2, axis=1)
        var = diff.var(axis=0, ddof=1) / part.count + prior + sim[ok].var(axis=0, ddof=1) / ok.sum()
        gap = np.mean(own, axis=0) - sim[ok].mean(axis=0)
        z = gap / np.sqrt(np.where(var > 0, var, np.inf))
        bound = threshold(int(ok.sum()), q.size)
        mean_own, mean_sim = np.mean(own, axis=0), sim[ok].mean(axis=0)
        for j in np.flatnonzero(np.abs(z) > bound):
            out.append(Disagreement(labels[q[j]], float(mean_own[j]), float(mean_sim[j]), float(np.sqrt(var[j])), z[j]))
    return out, dropped
