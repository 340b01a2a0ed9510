"""``identify``'s answer: ``Identification``, and its assembly from the search's state (the
covariance at the estimate, the warnings in a lab's terms, the fit's quality per recording)."""

from __future__ import annotations

import dataclasses
import functools
import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import scipy.stats

from .._estimation.estimate import estimate
from .._estimation.fit import ImpedanceFit, fit_impedance
from .._simulate import Trial
from . import calibration_prior, search
from . import layout as lay
from . import pool as pl
from .auxiliary import statistic_labels
from .diagnosis import motion_diagnosis, plausibility
from .indirect import predict
from .measured import unmeasured
from .selfcheck import cross_check

# An entry whose SE exceeds this multiple of its parameter's scale is reported as barely identifiable.
WEAK_RELATIVE_SE = 1.0
WHITENESS_LAGS = 20  # Ljung-Box lags of the residual
# An arm entry whose re-estimates spread more than this multiple of their linearised spread
# (``search.spread_ratio``; its SE is widened by it) is warned of: chosen on docs/identification.md
# section 6b's cells, where it flagged most recordings of the cell whose linearised intervals failed.
SPREAD_WARN = 1.4
# What a lab can change when the answer cannot be trusted, in the order to try.
ADVICE = (
    "record longer or with a larger perturbation, free the friction's parameters if they are held fixed, or "
    "report the classical route (its answer is in .classical)"
)


class RecordingFit(NamedTuple):
    """One recording's share of an ``Identification``: its ``group``, the model with the
    estimates in place (``trial``), ``vaf_position``, ``vaf_force``, ``whiteness_p``,
    ``stuck_fraction`` (as ``Identification``'s) and its ``classical`` answer."""

    group: str
    trial: Trial
    vaf_position: np.ndarray
    vaf_force: np.ndarray
    whiteness_p: np.ndarray
    stuck_fraction: np.ndarray
    classical: ImpedanceFit | None


@dataclasses.dataclass(frozen=True)
class Identification:
    """The result of ``identify`` (host values).

    Attributes:
        values: ``{name: array}`` the estimates, in each parameter's units and shape
            (``(2, 2)`` arm matrices indexed ``[output, input]``, ``(2,)`` friction per joint,
            ``(3,)`` the robot's inertia). With several groups of recordings, a per-group
            parameter is named ``"arm.stiffness@<group>"``.
        se: ``{name: array}`` their standard errors, same units and shapes.
        covariance: ``(n, n)`` covariance of every entry, in the order of ``labels``.
        labels: names of the entries, e.g. ``"arm.mass[0,1]"``.
        converged: whether the search settled (``message`` says why not).
        intervals_reliable: converged and nothing in ``warnings`` but the ``not_told`` note
            (whose intervals are the ranges those entries were allowed) and the advice on a
            calibration that widens the arm's SEs (``calibration_prior.widening``: they hold, wide).
        warnings: plain sentences on what not to trust.
        not_told: ``{label: (low, high)}``, entries of friction parameters the recording barely
            tells, with the range they were allowed (the nuisance prior's 95% range, within the
            parameter's physical range); ``interval`` gives that range for them.
        statistic: the arm's statistic, ``"efficient"`` or ``"welch"``.
        cost: ``(b - beta(p))^T W (b - beta(p)) / 2`` at the estimate (``W``: each statistic in
            units of its spread over the draws).
        iterations: Gauss-Newton steps taken.
        history: per step, ``cost`` (as ``cost``) before it and ``step_se``, its largest move
            in standard errors (``refused``: no fraction of it lowered the mismatch, so the slope
            was recomputed instead).
        draws: noise draws ``R`` behind the binding and the covariance.
        statistics: ``{label: value}`` the recording's statistics, by ``statistic_labels``.
        vaf_position, vaf_force: ``(2,)`` variance of the recorded ``x`` and ``F_h`` accounted
            for by the fitted model's noise-free simulation [%], per axis (of the first
            recording; ``recordings`` has every recording's).
        whiteness_p: ``(4,)`` Ljung-Box p-values of that simulation's residual (x1, x2, fh1,
            fh2; ``WHITENESS_LAGS`` lags): small when the noise is coloured, as it is in a
            loop; a fit-quality figure, not a test of the intervals.
        stuck_fraction: ``(2,)`` share of the record each joint stood still (``diagnosis.py``).
        classical: the Welch FRF + ``fit_impedance`` answer from the same recording
            (``None`` when the record is too short for two Welch segments).
        trial: the model with the estimates in place (the first recording's).
        time_s: wall time of the call [s]; forward_s: one noise-free simulation of the
            record, timed in the call [s] (the unit of ``time_s / forward_s``; the first
            recording's).
        recordings: per recording, a ``RecordingFit`` (its group, model with the estimates,
            fit quality and classical answer).
        spread_ratio: ``{label: float}`` through friction in a noisy loop, each entry's spread
            over re-estimates from recordings simulated at the estimate, one Gauss-Newton step
            past the linearisation, over their linearised spread (``search.spread_ratio``; on
            the internal scale, so for friction a log or logit's): 1 where the fit is linear over
            the intervals, above it where the friction bends it. ``se`` and ``covariance`` are
            widened by it where it is above 1; an arm entry above ``SPREAD_WARN`` is warned of
            (``bent``). Empty without friction or noise, with fewer than 11 draws, or where the
            check's simulations diverged (then a warning says so). From up to 14 re-estimates,
            so itself noisy (docs/identification.md 6b).
        disagreements: where the loop bends, the arm entries whose classical fit departs from
            what recordings simulated at the answer give by more than their combined uncertainty
            (``selfcheck.Disagreement``: label, the recording's classical value, the predicted
            one, the combined SE and ``z``); a warning names them and ``intervals_reliable`` is
            False (``selfcheck.py``).
    """

    values: dict
    se: dict
    covariance: np.ndarray
    labels: list
    converged: bool
    message: str
    intervals_reliable: bool
    warnings: list
    not_told: dict
    statistic: str
    cost: float
    iterations: int
    history: list
    draws: int
    statistics: dict
    vaf_position: np.ndarray
    vaf_force: np.ndarray
    whiteness_p: np.ndarray
    stuck_fraction: np.ndarray
    classical: ImpedanceFit | None
    trial: Trial
    time_s: float
    forward_s: float
    recordings: tuple = ()
    spread_ratio: dict = dataclasses.field(default_factory=dict)
    disagreements: tuple = ()

    @property
    def bent(self) -> dict:
        """``{label: spread ratio}``: the arm's entries warned of for spreading more than
        ``SPREAD_WARN`` times their linearised spread (``spread_ratio``)."""
        return bent_entries(self.spread_ratio)

    def interval(self, name: str, level: float = 0.95):
        """Two-sided normal ``level`` interval ``(low, high)`` of parameter ``name`` (for an entry
        in ``not_told``, the range it was allowed)."""
        z = scipy.stats.norm.ppf(0.5 + level / 2)
        low, high = self.values[name] - z * self.se[name], self.values[name] + z * self.se[name]
        for label, (lo, hi) in self.not_told.items():
            if label.startswith(name + "["):
                index = tuple(int(i) for i in label[len(name) + 1 : -1].split(","))
                low[index], high[index] = lo, hi
        return low, high

    def summary(self) -> str:
        """A few lines: convergence, warnings, then each parameter as value +- SE."""
        lines = [("converged" if self.converged else "NOT CONVERGED: " + self.message)]
        lines += ["WARNING: " + w for w in self.warnings]
        for name in self.values:
            v, s = np.asarray(self.values[name]), np.asarray(self.se[name])
            lines.append(f"{name}: {np.array2string(v, precision=4)} +- {np.array2string(s, precision=4)}")
        return "\n".join(lines)


@functools.partial(jax.jit, static_argnames=("layout", "numerics"))
def predict_jit(layout, model, p, f, numerics):
    """``indirect.predict`` as one compiled program."""
    return predict(layout, model, p, f, numerics)


def _ljung_box_p(e, lags: int):
    e = e - e.mean(axis=0)
    n = e.shape[0]
    denom = np.sum(e * e, axis=0)
    q = np.zeros(e.shape[1])
    with np.errstate(invalid="ignore", divide="ignore"):  # a residual of exact zeros (a noise-free fit) has no p
        for k in range(1, lags + 1):
            rho = np.sum(e[k:] * e[:-k], axis=0) / denom
            q += rho**2 / (n - k)
    return scipy.stats.chi2.sf(n * (n + 2) * q, lags)


def classical_fit(f, x, fh, acquisition, period):
    """The classical answer of one recording: Welch's estimate (segments that follow the record)
    and ``fit_impedance`` with the trial's acquisition model; ``None`` for a record too short."""
    try:
        est = estimate(f, x, fh, fs=1.0 / period)  # segments that follow the record (welch_segments)
    except ValueError:
        return None
    return fit_impedance(est, acquisition=acquisition, period=period, se="spectral")


def _warnings(problem: search.Problem, pool: pl.Pool, p, labels, values, se, cov_p) -> tuple[list, dict]:
    """Plain warnings, and the nuisance entries (friction, calibration) the recordings do not tell."""
    warnings = []
    if not problem.noisy:
        warnings.append(
            "the model has no noise (ideal sensors, no voluntary force): the standard errors are zero; give the "
            "model the recording's noise (Sensors, VoluntaryForce) for intervals"
        )
        return warnings, {}
    not_told = {}
    se_internal = np.sqrt(np.maximum(np.diag(cov_p), 0.0))
    nat_index = _natural_of_internal(pool)
    for k, mean in zip(problem.prior_index, problem.prior_mean, strict=True):
        if se_internal[k] > 0.5 * search.PRIOR_SD:
            ends = []
            for end in (-1.96, 1.96):  # the prior's 95% range, through the parameter's own map
                q = np.array(p, dtype=float)
                q[k] = mean + end * search.PRIOR_SD
                ends.append(np.asarray(pl.natural_with_jacobian(pool, jnp.asarray(q))[0]))
            for j in nat_index[k]:
                low, high = sorted((float(ends[0][j]), float(ends[1][j])))
                not_told[labels[j]] = (low, high)
    if not_told:
        told = ", ".join(f"{lab} (allowed {lo:.3g} to {hi:.3g})" for lab, (lo, hi) in not_told.items())
        warnings.append(
            f"the recording barely tells {told}: their intervals are the ranges they were allowed about the "
            "start, and the arm's intervals carry that uncertainty"
        )
    weak = _weak(pool, values, se)
    if weak:
        warnings.append(
            f"barely identifiable from this recording: {', '.join(weak)}; hold it fixed at a value known from "
            "elsewhere, or record with a perturbation that excites it"
        )
    return warnings, not_told


def _by_label(pool: pl.Pool, labels, per_internal) -> dict:
    """``{label: value}`` of each natural entry from a value per internal parameter (``{}`` without)."""
    if per_internal is None:
        return {}
    return {labels[j]: float(per_internal[k]) for k, entries in enumerate(_natural_of_internal(pool)) for j in entries}


def bent_entries(spread_ratio: dict) -> dict:
    """``{label: ratio}`` of the arm's entries whose ratio exceeds ``SPREAD_WARN``."""
    arm = {lab: r for lab, r in spread_ratio.items() if lab.split("[")[0].split("@")[0] in lay.ARM_PARAMETERS}
    return {lab: r for lab, r in arm.items() if r > SPREAD_WARN}


def _bent(spread_ratio: dict, seconds: float) -> list[str]:
    """A warning for ``bent_entries``, in a lab's terms, with the data that would bring them
    within ``SPREAD_WARN``: the excess variance, ``ratio^2 - 1``, falls with the estimate's
    variance, as one over the recorded time (``seconds``, every recording of the call)."""
    bent = bent_entries(spread_ratio)
    if not bent:
        return []
    times = (max(bent.values()) ** 2 - 1.0) / (SPREAD_WARN**2 - 1.0)
    entries = ", ".join(f"{lab} ({r:.2g} times)" for lab, r in bent.items())
    return [
        "the fit is not linear across these intervals (the robot's friction bends the loop there): re-estimates "
        f"from recordings simulated at the estimate spread wider than the straight line says for {entries}, and "
        "their intervals are widened by as much, which rests on a few re-estimates; record about "
        f"{times:.1f} times as much (about {times * seconds:.0f} s against these {seconds:.0f} s, in longer or "
        "more recordings) for intervals that need no widening"
    ]


def _cross_check(problem: search.Problem, state: search.Search, sens, recorded, pool: pl.Pool, labels):
    """``selfcheck.cross_check`` at the answer where the loop bends (friction in a noisy loop)
    and the arm's statistic is the efficient one; ``[]`` elsewhere."""
    if not (problem.chord and sens is not None) or all(part.arm_stat is None for part in problem.parts):
        return []
    internal = [labels[entries[0]] for entries in _natural_of_internal(pool)]
    found, _ = cross_check(problem, state.p, state.stats, sens, recorded, internal)
    return found


def _disagree(disagreements, values: dict, se: dict) -> list[str]:
    """A warning naming the arm entries where the classical fit and the answer disagree, with both
    values, and what a lab can change."""
    if not disagreements:
        return []
    entries = "; ".join(
        f"{d.label} {values[d.label]:.4g} +- {se[d.label]:.2g} here, the classical fit {d.classical:.4g} where "
        f"recordings simulated at this answer give {d.predicted:.4g} ({abs(d.z):.1f} combined SEs apart)"
        for d in disagreements
    )
    return [
        f"the classical fit of this recording disagrees with the answer beyond their combined uncertainty: {entries}. "
        f"The closed-loop model at this answer does not explain the recording, so its intervals are not to be "
        f"trusted: {ADVICE}"
    ]


def _unchecked(check) -> list[str]:
    """A warning where ``search.spread_ratio`` could not run for diverging simulations."""
    if check is None or check[0] is not None or not check[1]:
        return []
    _, dropped, count = check
    return [
        f"the intervals could not be checked: {dropped} of {count} recordings simulated near this answer went "
        "unstable (the arm, the robot's control and its friction together are near the edge of stability there), "
        f"so the answer is not to be trusted: {ADVICE}"
    ]


def _weak(pool: pl.Pool, values, se) -> list[str]:
    """Arm entries whose SE exceeds their matrix's largest entry (an off-diagonal entry near zero
    is not weak for being small)."""
    out = []
    est, err = pl.unflatten(pool, values), pl.unflatten(pool, se)
    for name, v in est.items():
        if name.split("@")[0] not in lay.ARM_PARAMETERS:
            continue
        scale, s = np.abs(v).max(), err[name]
        out += [
            f"{name}[{i},{j}] (SE {s[i, j]:.3g} against {v[i, j]:.3g})"
            for i, j in np.ndindex(2, 2)
            if s[i, j] > WEAK_RELATIVE_SE * scale
        ]
    return out


def _natural_of_internal(pool: pl.Pool) -> list[list[int]]:
    """For each internal parameter of ``p``, the natural entries it sets."""
    out, nat = [], 0
    for block in pool.blocks:
        layout = block.layout
        for k, name in enumerate(layout.names):
            if layout.symmetric[k]:
                out += [[nat], [nat + 1, nat + 2], [nat + 3]]
            else:
                out += [[nat + i] for i in range(layout.n_internal(k))]
            nat += int(np.prod(layout.shape(name), dtype=int))
    return out


def _fit(part: search.Part, p, numerics, x, fh, group):
    """A recording's fit quality at the estimate: ``(RecordingFit, diverged)``."""
    layout, model = part.layout, part.model
    y_fit, diverged = predict_jit(layout, model, jnp.asarray(p[part.index]), part.f, numerics)
    stuck = motion_diagnosis(model, x)
    y = np.concatenate([x, fh], axis=1)
    resid = y - np.asarray(y_fit)
    with np.errstate(invalid="ignore", divide="ignore"):  # a channel without variance (no arm: no force) has no VAF
        vaf = 100.0 * (1.0 - np.sum(resid**2, axis=0) / np.sum((y - y.mean(axis=0)) ** 2, axis=0))
    fit = RecordingFit(
        group=group,
        trial=lay.with_values(layout, model, jnp.asarray(p[part.index])),
        vaf_position=vaf[:2],
        vaf_force=vaf[2:],
        whiteness_p=_ljung_box_p(resid, WHITENESS_LAGS),
        stuck_fraction=stuck.fraction,
        classical=classical_fit(part.f, x, fh, model.acquisition, model.period),
    )
    return fit, bool(diverged), stuck


def assemble(problem: search.Problem, state: search.Search, pool: pl.Pool, recorded, statistic, t_start, forward_s):
    """The ``Identification`` of the search's final ``state``; ``recorded``: per recording ``(part,
    x, fh)``, the index of its binding in ``problem.parts`` and its recording."""
    p = state.p
    cov_p, problems, check, sens = search.final_covariance(problem, state)
    shares = calibration_prior.carried(problem, state)  # a lab's calibration's uncertainty, carried
    cov_own = cov_p
    cov_p = cov_p + sum(shares.values(), np.zeros_like(cov_p))
    fits, stuck = [], []
    for (t, x, fh), group in zip(recorded, pool.groups, strict=True):
        fit, diverged, st = _fit(problem.parts[t], p, problem.numerics, x, fh, group)
        fits.append(fit)
        stuck.append(st)
        if diverged:
            problems = problems + ("the model at this answer is unstable when simulated without noise",)
    values, g = (np.asarray(v) for v in pl.natural_with_jacobian(pool, jnp.asarray(p)))
    cov = g @ cov_p @ g.T
    se = np.sqrt(np.maximum(np.diag(cov), 0.0))
    labels = pool.labels()
    warnings, not_told = _warnings(problem, pool, p, labels, values, se, cov_p)
    spread_ratio = _by_label(pool, labels, None if check is None else check[0])
    seconds = sum(x.shape[0] for _, x, _ in recorded) * problem.parts[0].model.period
    warnings = warnings + _bent(spread_ratio, seconds) + _unchecked(check)
    widened = calibration_prior.widening(shares, g @ cov_own @ g.T, g, labels)  # advice: the intervals hold
    if problem.noisy:  # without noise there are no intervals to have measured
        warnings = warnings + unmeasured(problem.parts[0].model)
    disagreements = _cross_check(problem, state, sens, recorded, pool, labels)
    warnings = warnings + _disagree(
        disagreements, dict(zip(labels, values, strict=True)), dict(zip(labels, se, strict=True))
    )
    warnings = warnings + plausibility(pl.unflatten(pool, values), pl.unflatten(pool, se))  # no human arm's
    advice = [a for st in stuck for a in st.advice]
    message = "; ".join(problems)
    if problems and advice:  # why, in a lab's terms, before the search's own account
        message = f"{advice[0]} (the search: {message})"
    elif problems:
        message = f"{message}: {ADVICE}"
    elif any("barely identifiable" in w for w in warnings):
        warnings = warnings + list(dict.fromkeys(advice))
    first = fits[0]
    m = len(statistic_labels(problem.parts[0].layout))
    return Identification(
        values=pl.unflatten(pool, values),
        se=pl.unflatten(pool, se),
        covariance=cov,
        labels=labels,
        converged=not problems,
        message=message,
        intervals_reliable=not problems and len(warnings) == bool(not_told),
        warnings=warnings + widened,
        not_told=not_told,
        statistic=statistic,
        cost=state.cost,
        iterations=state.iterations,
        history=list(state.history),
        draws=problem.n_draws,
        statistics=dict(zip(statistic_labels(problem.parts[0].layout), (float(v) for v in problem.b[:m]), strict=True)),
        vaf_position=first.vaf_position,
        vaf_force=first.vaf_force,
        whiteness_p=first.whiteness_p,
        stuck_fraction=first.stuck_fraction,
        classical=first.classical,
        trial=first.trial,
        time_s=time.perf_counter() - t_start,
        forward_s=forward_s,
        recordings=tuple(fits),
        spread_ratio=spread_ratio,
        disagreements=tuple(disagreements),
    )
