"""Identify an arm (and the robot's friction) through the closed-loop model: ``identify``.

Given the commanded ``F_Delta`` and the recorded hand position and force, estimate named
parameters of a trial by **indirect inference** (``indirect.py``): find the parameters at
which recordings simulated through the friction-aware closed loop, with the trial's own
noise, give on average the same statistics as the lab's recording.

The statistics (``auxiliary.py``): for the arm, by default the **efficient statistic**
(``efficient.py``), one generalised least-squares step of the frictionless loop linearised
about rest, with the loop's coloured noise whitened by its Kalman filter, centred where the
recording itself puts the arm (``efficient.fit_linear``). Near a linear loop its variance is
the Cramér-Rao bound (``bound.py``), and the simulation corrects what the linear model leaves
out (friction, sampling, the robot's kinematics). ``statistic="welch"`` is the classical
Welch fit instead (1 Hz bins: blind at the low frequencies where stiffness shows). For the
friction, a regression of the joint torques.

Why match statistics and not fit the signals: with the person's own force and the sensors'
noise fed back through a loop with friction, the noise-free simulation is not the mean of
the noisy loop, and an output-error fit's 95% intervals covered the truth 42-74% of the time
(docs/identification.md). Statistics matched in expectation carry all of that into the
simulation: the estimate is consistent, and its covariance comes from the spread of the
statistics over noise draws, the loop's feedback and coloured noise included.

The search (``search.py``): Gauss-Newton on the mismatch of statistics, the binding's
Jacobian reused between steps, friction parameters held by a wide prior about their start
(nuisances for the arm: one the recording cannot tell, such as the Coulomb torque under
IMBIC, which cancels it, is flagged in ``not_told`` and its uncertainty carried into the
arm's intervals). Then the result's assembly: the covariance at the estimate, warnings in a
lab's terms (``diagnosis.py``: joints that stood still), fit quality and the classical answer.
"""

from __future__ import annotations

import dataclasses
import functools
import time

import jax
import jax.numpy as jnp
import numpy as np
import scipy.stats

from .._checks import as_float64, check_int, require_x64
from .._estimation.estimate import estimate
from .._estimation.fit import ImpedanceFit, fit_impedance
from .._estimation.welch import check_finite
from .._simulate import Trial
from .._solver.numerics import Numerics
from . import efficient, indirect, search
from . import layout as lay
from .auxiliary import check_statistic_record, statistic_labels, statistics
from .bound import has_friction, is_near_linear
from .diagnosis import motion_diagnosis
from .indirect import predict
from .predict import check_sampling

# An entry whose SE exceeds this multiple of its parameter's scale is reported as barely identifiable.
WEAK_RELATIVE_SE = 1.0
WHITENESS_LAGS = 20  # Ljung-Box lags of the residual
MIN_SAMPLES = 1024  # the Welch statistic's least at 1 kHz (4 segments of 256 samples: 3 bins to 15 Hz)
CHANNELS = ("x1", "x2", "fh1", "fh2")


@dataclasses.dataclass(frozen=True)
class Identification:
    """The result of ``identify`` (host values).

    Attributes:
        values: ``{name: array}`` the estimates, in each parameter's units and shape
            (``(2, 2)`` arm matrices indexed ``[output, input]``, ``(2,)`` friction per joint).
        se: ``{name: array}`` their standard errors, same units and shapes.
        covariance: ``(n, n)`` covariance of every entry, in the order of ``labels``.
        labels: names of the entries, e.g. ``"arm.mass[0,1]"``.
        converged: whether the search settled (``message`` says why not).
        intervals_reliable: converged and nothing in ``warnings`` but the ``not_told`` note
            (whose intervals are the ranges those entries were allowed).
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
            for by the fitted model's noise-free simulation [%], per axis.
        whiteness_p: ``(4,)`` Ljung-Box p-values of that simulation's residual (x1, x2, fh1,
            fh2; ``WHITENESS_LAGS`` lags): small when the noise is coloured, as it is in a
            loop; a fit-quality figure, not a test of the intervals.
        stuck_fraction: ``(2,)`` share of the record each joint stood still (``diagnosis.py``).
        classical: the Welch FRF + ``fit_impedance`` answer from the same recording
            (``None`` when the record is too short for two Welch segments).
        trial: the model with the estimates in place.
        time_s: wall time of the call [s]; forward_s: one noise-free simulation of the
            record, timed in the call [s] (the unit of ``time_s / forward_s``).
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


def check_recording(f, x, fh, where: str):
    """``(f, x, fh)`` as float64 ``(N, 2)`` arrays: one-line errors for a wrong shape, NaN or inf
    (naming the array and sample), mismatched lengths or fewer than ``MIN_SAMPLES`` samples."""
    arrays = {}
    for name, a in (("f", f), ("x", x), ("fh", fh)):
        arr = as_float64(name, a, where=where)
        if arr.ndim != 2 or arr.shape[1] != 2:
            raise ValueError(f"{where}: {name} must have shape (N, 2), got {arr.shape}")
        check_finite(name, arr, where=where)
        arrays[name] = arr
    lengths = {k: v.shape[0] for k, v in arrays.items()}
    if len(set(lengths.values())) > 1:
        raise ValueError(f"{where}: f, x and fh must have the same length, got {lengths}")
    if lengths["f"] < MIN_SAMPLES:
        raise ValueError(f"{where}: the record must hold at least {MIN_SAMPLES} samples, got {lengths['f']}")
    return arrays["f"], arrays["x"], arrays["fh"]


@functools.partial(jax.jit, static_argnames="layout")
def _statistics(layout, model, f, x, fh, arm_stat):
    return statistics(layout, model, f, x, fh, arm_stat)


@functools.partial(jax.jit, static_argnames=("layout", "numerics"))
def _predict(layout, model, p, f, numerics):
    return predict(layout, model, p, f, numerics)


def _ljung_box_p(e, lags: int):
    e = e - e.mean(axis=0)
    n = e.shape[0]
    denom = np.sum(e * e, axis=0)
    q = np.zeros(e.shape[1])
    for k in range(1, lags + 1):
        rho = np.sum(e[k:] * e[:-k], axis=0) / denom
        q += rho**2 / (n - k)
    return scipy.stats.chi2.sf(n * (n + 2) * q, lags)


def _classical(f, x, fh, acquisition, period):
    try:
        est = estimate(f, x, fh, fs=1.0 / period)  # segments that follow the record (welch_segments)
    except ValueError:
        return None
    return fit_impedance(est, acquisition=acquisition, period=period, se="spectral")


def _check(model, f, x, fh, free, symmetric, statistic, numerics, draws, jacobian_draws, max_steps):
    """Every one-line refusal before long work; the checked values."""
    if not isinstance(model, Trial):
        raise ValueError(f"identify: model must be a Trial (from make_trial), got {type(model).__name__}")
    layout = lay.make_layout(free, symmetric, friction=model.friction)
    f, x, fh = check_recording(f, x, fh, "identify")
    check_statistic_record(f.shape[0], model.period, "identify")
    numerics, draws, jacobian_draws = check_sampling("identify", statistic, numerics, draws, jacobian_draws)
    max_steps = check_int("max_steps", max_steps, minimum=1)
    for name, arr in (("x", x), ("fh", fh)):
        flat = [f"{name}[:, {i}]" for i in range(2) if not float(jnp.std(arr[:, i])) > 0]
        if flat:
            raise ValueError(f"identify: the recorded channel(s) {flat} are constant; nothing to fit")
    return layout, f, x, fh, numerics, draws, jacobian_draws, max_steps


def _arm_statistic(layout, model, p, f, x, fh, statistic, numerics, keys):
    """The arm's statistic (``None``: Welch), the search's start and the statistic's name.

    ``auto`` takes the efficient statistic unless the model's loop is far from linear
    (``bound.is_near_linear``: stick-slip), where the Welch fit is the safer. The efficient
    statistic is centred where the recording puts the arm through the linear loop
    (``efficient.fit_linear``), and the search starts there, unless the model diverges there:
    then at the model's start. Under friction the innovations are weighed by their spread in
    recordings simulated at the model's start (``efficient.excess_weight``)."""
    arm = indirect.arm_layout(layout)
    if arm is None or statistic == "welch" or (statistic == "auto" and not is_near_linear(model, f, numerics)):
        return None, p, "welch"
    idx = indirect.arm_index(layout)
    weight = None
    if has_friction(model) and model.noisy:
        # friction's effect is no part of the linear loop: weigh the innovations by their spread
        # in recordings simulated with it, at the model's start, before the fit uses them
        weight_keys = keys[: indirect.weight_draws(keys.shape[0])]
        weight = indirect.statistic_weight(layout, model, jnp.asarray(p), f, weight_keys, numerics)
        # one program in flight at a time: two that split over the CPU devices and meet at
        # collectives, queued together, can each hold a thread the other waits for
        weight = jax.block_until_ready(weight)
        if not np.all(np.isfinite(np.asarray(weight))):
            raise ValueError("identify: noisy simulations of the model diverge at the start; choose another start")
    ref, _ = efficient.fit_linear(arm, model, p[idx], f, efficient.recorded(model, x, fh), weight)
    centred = p.copy()
    centred[idx] = ref
    start = centred if not bool(_predict(layout, model, jnp.asarray(centred), f, numerics)[1]) else p
    stat = indirect.arm_statistic(layout, model, jnp.asarray(centred), f, weight)
    return jax.block_until_ready(stat), start, "efficient"


def identify(
    model: Trial,
    f,
    x,
    fh,
    *,
    free,
    symmetric=(),
    statistic: str = "auto",
    numerics: Numerics | None = None,
    key=None,
    draws: int = 64,
    jacobian_draws: int = 8,
    max_steps: int = 20,
) -> Identification:
    """Estimate parameters of ``model`` from a recording, through the closed-loop simulation.

    Args:
        model: a ``Trial`` holding every fixed setting (robot, controller, acquisition,
            sensors' and voluntary force's noise levels, which the intervals rest on) and the
            starting values of the free parameters.
        f: the commanded perturbation ``F_Delta`` ``(N, 2)`` [N].
        x, fh: the recorded hand position [m] and force [N], ``(N, 2)`` each.
        free: names of the parameters to estimate, from ``"arm.mass"``, ``"arm.damping"``,
            ``"arm.stiffness"`` (full 2x2) and the friction law's ``IDENTIFIABLE`` ones as
            ``"friction.<name>"`` (per joint): LuGre's ``tau_c``, ``tau_s``, ``sigma0``,
            ``sigma1``, ``sigma2``; CoulombViscous's ``tau_c``, ``viscous``.
        symmetric: free arm matrices to constrain symmetric (3 numbers instead of 4).
        statistic: the arm's statistic: ``"efficient"`` (module docstring), ``"welch"``, or
            ``"auto"`` (default: efficient unless the model's loop is far from linear).
        numerics: integration settings (default ``IDENTIFY_NUMERICS``, ``GradedARK4`` at 4
            substeps: converged at every friction in [0, 4] N m).
        key: ``jax.random`` key of the simulated noise draws (default ``key(0)``: the result
            is deterministic).
        draws: noise draws ``R`` behind the binding and the covariance (>= 8; rounded up to
            a multiple of the local devices). The SEs carry a Monte Carlo error of about
            ``1 / sqrt(2 R)``; the estimate's variance grows by ``1 / R``.
        jacobian_draws: draws averaged in the Jacobian ``A`` (1 to ``draws``).
        max_steps: Gauss-Newton steps at most.

    Returns an ``Identification``. Raises a one-line ``ValueError`` before any long
    computation for an unknown parameter, NaN or inf in the recording, mismatched
    lengths, or a start at which the model diverges. A fit that does not converge is
    returned with ``converged=False`` and the reason in ``message``.
    """
    require_x64("identify")
    t_start = time.perf_counter()
    checked = _check(model, f, x, fh, free, symmetric, statistic, numerics, draws, jacobian_draws, max_steps)
    layout, f, x, fh, numerics, draws, jacobian_draws, max_steps = checked
    key = jax.random.key(0) if key is None else key
    p, forward_s = _checked_start(layout, model, f, numerics)
    n_draws, n_jac = indirect.draw_counts(model, draws, jacobian_draws)
    keys = jax.random.split(key, n_draws)
    arm_stat, start, statistic = _arm_statistic(layout, model, p, f, x, fh, statistic, numerics, keys)
    problem = _problem(layout, model, f, x, fh, numerics, keys, n_jac, arm_stat)
    state = _init(problem, start, p)
    while not state.done:
        state = search.step(problem, state, max_steps)
    return _assemble(problem, state, f, x, fh, statistic, t_start, forward_s)


def _checked_start(layout, model, f, numerics):
    """The packed start ``p``, and the wall time [s] of one noise-free simulation there; a
    one-line error if the model diverges at the start."""
    p = np.asarray(lay.pack(layout, model))
    _, diverged = _predict(layout, model, jnp.asarray(p), f, numerics)
    if bool(diverged):
        start = {n: np.asarray(v).tolist() for n, v in lay.split(layout, jnp.asarray(p), model).items()}
        raise ValueError(f"identify: the model diverges at the starting values {start}; choose another start")
    t0 = time.perf_counter()
    jax.block_until_ready(_predict(layout, model, jnp.asarray(p), f, numerics))
    return p, time.perf_counter() - t0


def _problem(layout, model, f, x, fh, numerics, keys, n_jac, arm_stat) -> search.Problem:
    """What the search holds fixed: the recording's statistics, the nuisance prior and the
    slack; a one-line error for statistics the recording leaves undefined."""
    b = np.asarray(_statistics(layout, model, f, x, fh, arm_stat))
    if not np.all(np.isfinite(b)):
        bad = [lab for lab, v in zip(statistic_labels(layout), b, strict=True) if not np.isfinite(v)]
        raise ValueError(
            f"identify: the recording's statistics {', '.join(bad)} are not finite (a joint that never moves "
            "leaves its friction unmeasured); free fewer friction parameters or record with more motion"
        )
    noisy, packed = model.noisy, np.asarray(lay.pack(layout, model))
    # the nuisance prior: friction parameters of a noisy model (without noise there is no spread to weigh it by)
    prior_index = np.setdiff1d(np.arange(packed.size), indirect.arm_index(layout)) if noisy else np.zeros(0, dtype=int)
    prior_mean = packed[prior_index]
    slack = b.size / keys.shape[0] if noisy else 1e-24 * (1.0 + float(b @ b))  # the binding's own MC jitter
    statistics_and_prior = np.concatenate([b, prior_mean])
    return search.Problem(
        layout, model, f, numerics, keys, n_jac, noisy, statistics_and_prior, arm_stat, prior_index, prior_mean, slack
    )


def _init(problem: search.Problem, start, given) -> search.Search:
    """The search's first state at ``start``; if the model's noisy simulations diverge there
    (the linear fit's start, which no noise-free run checked), at the user's ``given`` start."""
    try:
        return search.init(problem, start)
    except ValueError:
        if start is given:
            raise
        return search.init(problem, given)


def _warnings(problem: search.Problem, p, labels, values, se, cov_p) -> tuple[list, dict]:
    """Plain warnings, and the friction entries the recording does not tell."""
    layout, warnings = problem.layout, []
    if not problem.noisy:
        warnings.append(
            "the model has no noise (ideal sensors, no voluntary force): the standard errors are zero; give the "
            "model the recording's noise (Sensors, VoluntaryForce) for intervals"
        )
        return warnings, {}
    not_told = {}
    se_internal = np.sqrt(np.maximum(np.diag(cov_p), 0.0))
    nat_index = _natural_of_internal(layout)
    for k, mean in zip(problem.prior_index, problem.prior_mean, strict=True):
        if se_internal[k] > 0.5 * search.PRIOR_SD:
            ends = []
            for end in (-1.96, 1.96):  # the prior's 95% range, through the parameter's own map
                q = np.array(p, dtype=float)
                q[k] = mean + end * search.PRIOR_SD
                ends.append(np.asarray(lay.natural_with_jacobian(layout, jnp.asarray(q), problem.model)[0]))
            for j in nat_index[k]:
                low, high = sorted((float(ends[0][j]), float(ends[1][j])))
                not_told[labels[j]] = (low, high)
    if not_told:
        told = ", ".join(f"{lab} (allowed {lo:.3g} to {hi:.3g})" for lab, (lo, hi) in not_told.items())
        warnings.append(
            f"the recording barely tells {told}: their intervals are the ranges they were allowed about the "
            "start, and the arm's intervals carry that uncertainty"
        )
    # an arm entry is weak when its SE exceeds its matrix's largest entry (an off-diagonal entry
    # near zero is not weak for being small)
    weak = []
    for name, v in lay.unflatten(layout, values).items():
        if name not in lay.ARM_PARAMETERS:
            continue
        scale = np.abs(v).max()
        s = lay.unflatten(layout, se)[name]
        weak += [
            f"{name}[{i},{j}] (SE {s[i, j]:.3g} against {v[i, j]:.3g})"
            for i, j in np.ndindex(2, 2)
            if s[i, j] > WEAK_RELATIVE_SE * scale
        ]
    if weak:
        warnings.append(
            f"barely identifiable from this recording: {', '.join(weak)}; hold it fixed at a value known from "
            "elsewhere, or record with a perturbation that excites it"
        )
    return warnings, not_told


def _natural_of_internal(layout: lay.Layout) -> list[list[int]]:
    """For each internal parameter, the natural entries it sets."""
    out, nat = [], 0
    for k, name in enumerate(layout.names):
        if layout.symmetric[k]:
            out += [[nat], [nat + 1, nat + 2], [nat + 3]]
        else:
            out += [[nat + i] for i in range(layout.n_internal(k))]
        nat += int(np.prod(layout.shape(name)))
    return out


def _assemble(problem: search.Problem, state: search.Search, f, x, fh, statistic, t_start, forward_s) -> Identification:
    layout, model, p = problem.layout, problem.model, state.p
    cov_p, problems = search.final_covariance(problem, state)
    y_fit, diverged_fit = _predict(layout, model, jnp.asarray(p), f, problem.numerics)
    if bool(diverged_fit):
        problems = problems + ("the fitted model diverges",)
    values, g = (np.asarray(v) for v in lay.natural_with_jacobian(layout, jnp.asarray(p), model))
    cov = g @ cov_p @ g.T
    se = np.sqrt(np.maximum(np.diag(cov), 0.0))
    labels = layout.labels()
    warnings, not_told = _warnings(problem, p, labels, values, se, cov_p)
    stuck = motion_diagnosis(model, x)
    message = "; ".join(problems)
    if problems and stuck.advice:  # why, in a lab's terms, before the search's own account
        message = f"{stuck.advice[0]} (the search: {message})"
    elif any("barely identifiable" in w for w in warnings):
        warnings = warnings + stuck.advice
    y = np.concatenate([x, fh], axis=1)
    resid = y - np.asarray(y_fit)
    vaf = 100.0 * (1.0 - np.sum(resid**2, axis=0) / np.sum((y - y.mean(axis=0)) ** 2, axis=0))
    return Identification(
        values=lay.unflatten(layout, values),
        se=lay.unflatten(layout, se),
        covariance=cov,
        labels=labels,
        converged=not problems,
        message=message,
        intervals_reliable=not problems and len(warnings) == bool(not_told),
        warnings=warnings,
        not_told=not_told,
        statistic=statistic,
        cost=state.cost,
        iterations=state.iterations,
        history=list(state.history),
        draws=problem.keys.shape[0],
        statistics=dict(
            zip(
                statistic_labels(layout),
                (float(v) for v in problem.b[: problem.b.size - problem.prior_index.size]),
                strict=True,
            )
        ),
        vaf_position=vaf[:2],
        vaf_force=vaf[2:],
        whiteness_p=_ljung_box_p(resid, WHITENESS_LAGS),
        stuck_fraction=stuck.fraction,
        classical=_classical(f, x, fh, model.acquisition, model.period),
        trial=lay.with_values(layout, model, jnp.asarray(p)),
        time_s=time.perf_counter() - t_start,
        forward_s=forward_s,
    )
