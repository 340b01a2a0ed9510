"""Identify an arm (and the robot's friction) through the closed-loop model: ``identify``.

Given the commanded ``F_Delta`` and the recorded hand position and force, estimate named
parameters of a trial by **indirect inference** (``indirect.py``): find the parameters at
which recordings simulated through the friction-aware closed loop, with the trial's own
noise, give on average the same statistics as the lab's recording (``auxiliary.py``: the
classical impedance fit for the arm, a regression of the joint torques for the friction).

Why this and not a fit of the simulated signals to the recorded ones: with the person's
own force and the sensors' noise fed back through a loop with friction, the noise-free
simulation is not the mean of the noisy loop, and an output-error fit was biased and
nonlinear in the noise: its 95% intervals covered the truth 42-74% of the time
(docs/identification.md, section 2). Statistics matched in expectation carry all of that
into the simulation: the estimate is consistent, and its covariance comes from the spread
of the statistics over noise draws, the loop's feedback and coloured noise included.

Steps: (1) the statistics of the recording; (2) Gauss-Newton steps on the weighted mismatch
``b - beta(p)`` from the model's starting values, the binding's Jacobian ``A`` reused
between them (a chord) and recomputed after a step of more than ``JACOBIAN_REUSE_SE``
standard errors or one that fails; a step is halved while a draw diverges or the mismatch
grows; stop when a step moves every parameter by less than ``CONVERGED_FRACTION`` of its
SE; (3) the covariance (``indirect.covariance``) at the estimate; (4) fit quality (VAF,
residual whiteness of the noise-free fitted model) and the classical answer alongside.
Why not optimistix's least-squares solvers: the cost is in Monte Carlo draws and the
Jacobian is the expensive part, so it is reused across steps (they would recompute it or
run a line search through it), and the stopping rule is in standard errors that the draws
at each step give.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time

import jax
import jax.numpy as jnp
import numpy as np
import scipy.stats

from .._checks import as_float64, check_int, require_x64
from .._estimation.fit import ImpedanceFit, fit_impedance
from .._estimation.welch import check_finite, estimate
from .._simulate import Trial
from .._solver.numerics import Numerics
from . import indirect
from . import layout as lay
from .auxiliary import statistic_labels, statistics
from .indirect import IDENTIFY_NUMERICS, predict

CONVERGED_FRACTION = 0.15  # a step below this many SEs: converged (the binding's own MC error is 1/sqrt(R) SE)
JACOBIAN_REUSE_SE = 3.0  # A computed within this many SEs of the estimate serves its covariance
HALVINGS = 6  # a step is halved at most this many times while a draw diverges or the mismatch grows
# An entry whose SE exceeds this multiple of its parameter's scale is reported as barely identifiable.
WEAK_RELATIVE_SE = 1.0
WHITENESS_LAGS = 20  # Ljung-Box lags of the residual
MIN_SAMPLES = 1000
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
        converged: whether the fit is sound (see the module docstring); ``message`` says why not.
        intervals_reliable: converged and every parameter identifiable (``warnings`` empty).
        warnings: plain sentences on what not to trust.
        cost: ``(b - beta(p))^T W (b - beta(p)) / 2`` at the estimate (``W``: each statistic in
            units of its spread over the draws; 0 at an exact root, as with one statistic per
            parameter).
        iterations: Gauss-Newton steps taken.
        history: per step, ``cost`` (as ``cost``) before it and ``step_se``, its largest move
            in standard errors (``refused``: no fraction of it lowered the mismatch, so the slope
            was recomputed instead).
        draws: noise draws ``R`` behind the binding and the covariance.
        statistics: ``{label: value}`` the recording's statistics, by ``statistic_labels``
            (the classical ``M, B, K`` entries, e.g. ``"arm.mass[0,1]"``; with friction free,
            per joint the friction regression's coefficients and the log RMS speed, e.g.
            ``"friction coulomb[1]"``).
        vaf_position, vaf_force: ``(2,)`` variance of the recorded ``x`` and ``F_h`` accounted
            for by the fitted model's noise-free simulation [%], per axis.
        whiteness_p: ``(4,)`` Ljung-Box p-values of that simulation's residual (x1, x2, fh1,
            fh2; ``WHITENESS_LAGS`` lags): small when the noise (the person's force, sensors)
            is coloured, as it is in a loop; a fit-quality figure, not a test of the intervals.
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
    cost: float
    iterations: int
    history: list
    draws: int
    statistics: dict
    vaf_position: np.ndarray
    vaf_force: np.ndarray
    whiteness_p: np.ndarray
    classical: ImpedanceFit | None
    trial: Trial
    time_s: float
    forward_s: float

    def interval(self, name: str, level: float = 0.95):
        """Two-sided normal ``level`` interval ``(low, high)`` of parameter ``name``."""
        z = scipy.stats.norm.ppf(0.5 + level / 2)
        return self.values[name] - z * self.se[name], self.values[name] + z * self.se[name]

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
def _statistics(layout, model, f, x, fh):
    return statistics(layout, model, f, x, fh)


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
    n = f.shape[0]
    nperseg = min(8192, 2 ** int(math.floor(math.log2(n / 2))))
    try:
        est = estimate(f, x, fh, fs=1.0 / period, nperseg=nperseg, noverlap=3 * nperseg // 4, errors=True)
    except ValueError:
        return None
    return fit_impedance(est, acquisition=acquisition, period=period, se="spectral")


def _binding(layout, model, p, f, keys, numerics):
    stats, diverged = indirect.binding_draws(layout, model, jnp.asarray(p), f, keys, numerics)
    stats, diverged = np.asarray(stats), np.asarray(diverged)
    return stats.mean(axis=0), stats, bool(diverged.any())


def identify(
    model: Trial,
    f,
    x,
    fh,
    *,
    free,
    symmetric=(),
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
            ``"arm.stiffness"`` (full 2x2), ``"friction.tau_c"``, ``"friction.tau_s"``,
            ``"friction.sigma0"``, ``"friction.sigma1"``, ``"friction.sigma2"`` (per joint).
        symmetric: free arm matrices to constrain symmetric (3 numbers instead of 4).
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
    if not isinstance(model, Trial):
        raise ValueError(f"identify: model must be a Trial (from make_trial), got {type(model).__name__}")
    layout = lay.make_layout(free, symmetric)
    f, x, fh = check_recording(f, x, fh, "identify")
    draws = check_int("draws", draws, minimum=8)
    jacobian_draws = check_int("jacobian_draws", jacobian_draws, minimum=1)
    if jacobian_draws > draws:  # the Jacobian's draws are the first of the statistics' draws
        raise ValueError(f"identify: jacobian_draws {jacobian_draws} must be at most draws {draws}")
    max_steps = check_int("max_steps", max_steps, minimum=1)
    numerics = IDENTIFY_NUMERICS if numerics is None else numerics
    if not isinstance(numerics, Numerics):
        raise ValueError(f"identify: numerics must be a Numerics, got {type(numerics).__name__}")
    key = jax.random.key(0) if key is None else key
    p = np.asarray(lay.pack(layout, model))
    for name, arr in (("x", x), ("fh", fh)):
        flat = [f"{name}[:, {i}]" for i in range(2) if not float(jnp.std(arr[:, i])) > 0]
        if flat:
            raise ValueError(f"identify: the recorded channel(s) {flat} are constant; nothing to fit")
    _, diverged = _predict(layout, model, jnp.asarray(p), f, numerics)
    if bool(diverged):
        start = {n: np.asarray(v).tolist() for n, v in lay.split(layout, jnp.asarray(p), model).items()}
        raise ValueError(f"identify: the model diverges at the starting values {start}; choose another start")
    t0 = time.perf_counter()
    jax.block_until_ready(_predict(layout, model, jnp.asarray(p), f, numerics))
    forward_s = time.perf_counter() - t0

    noisy = not (model.sensors.ideal and model.voluntary is None)
    n_draws, n_jac = indirect.draw_counts(model, draws, jacobian_draws)
    keys = jax.random.split(key, n_draws)
    b = np.asarray(_statistics(layout, model, f, x, fh))
    if not np.all(np.isfinite(b)):
        bad = [lab for lab, v in zip(statistic_labels(layout), b, strict=True) if not np.isfinite(v)]
        raise ValueError(
            f"identify: the recording's statistics {', '.join(bad)} are not finite (a joint that never moves "
            "leaves its friction unmeasured); free fewer friction parameters or record with more motion"
        )
    mean, stats, diverged = _binding(layout, model, p, f, keys, numerics)
    if diverged:
        raise ValueError("identify: noisy simulations of the model diverge at the start; choose another start")

    def jacobian(q):
        jac, div = indirect.binding_jacobian(layout, model, jnp.asarray(q), f, keys[:n_jac], numerics)
        jac = np.asarray(jac)
        if bool(div) or not np.all(np.isfinite(jac)):
            return None
        return jac

    jac, jac_at = jacobian(p), p
    w = np.asarray(indirect.weights(stats, jac))  # held while the slope is: costs compare under one W

    def cost_of(m):
        d = b - m
        return 0.5 * float(d @ (w * d))

    problems, history = [], []
    iterations, se_p = 0, None
    if jac is None:
        problems.append("the binding's Jacobian is not finite at the start")
    cost = cost_of(mean)
    # the binding's own Monte Carlo jitter of the cost: a step within it is no worse
    slack = b.size / n_draws if noisy else 1e-24 * (1.0 + float(b @ b))
    while jac is not None:
        step = np.asarray(indirect.gauss_newton_step(jac, w, b - mean))
        if not np.all(np.isfinite(step)):
            problems.append("the binding's Jacobian is singular: some parameter does not move the statistics")
            break
        se_p = np.sqrt(np.diag(np.asarray(indirect.covariance(jac, stats, n_draws, w))))
        history.append(dict(cost=cost, step_se=float(np.max(np.abs(step) / se_p)) if noisy else math.nan))
        if noisy and np.all(np.abs(step) <= CONVERGED_FRACTION * se_p):
            break
        if not noisy and np.all(np.abs(step) <= 1e-10 * (1.0 + np.abs(p))):
            break  # noise-free: converged to round-off
        if iterations == max_steps:
            problems.append(f"the iteration did not settle in {max_steps} steps")
            break
        # a step is kept when its simulations are sound and it does not raise the mismatch; a
        # slope that fails twice is refreshed here first, a fresh one is halved further
        stale = not np.array_equal(jac_at, p)
        scale, kept = 1.0, False
        for _ in range(2 if stale else HALVINGS + 1):
            trial_p = p + scale * step
            t_mean, t_stats, t_div = _binding(layout, model, trial_p, f, keys, numerics)
            t_cost = cost_of(t_mean) if np.all(np.isfinite(t_mean)) else math.inf
            if not t_div and t_cost < cost + slack:
                kept = True
                break
            scale *= 0.5
        if kept:
            p, mean, stats, cost = trial_p, t_mean, t_stats, t_cost
            iterations += 1
        else:
            history[-1]["refused"] = True
        if not kept or not np.all(np.abs(scale * step) <= JACOBIAN_REUSE_SE * se_p):  # a new slope
            new = jacobian(p) if (stale or kept) else None
            if new is None:
                if not kept:
                    problems.append(
                        f"no step from iteration {iterations} kept the simulations sound and lowered the mismatch"
                    )
                    break
                continue
            jac, jac_at, w = new, p, np.asarray(indirect.weights(stats, new))
            cost = cost_of(mean)
    # the covariance wants A at the estimate; one computed within a few SEs of it is as good
    if jac is not None and se_p is not None and not np.all(np.abs(p - jac_at) <= JACOBIAN_REUSE_SE * se_p):
        jac = jacobian(p)
        if jac is None:
            problems.append("the binding's Jacobian is not finite at the estimate")
    if jac is not None:
        cov_p = np.asarray(indirect.covariance(jac, stats, n_draws)) if noisy else np.zeros((p.size, p.size))
    else:
        cov_p = np.full((p.size, p.size), np.nan)
    y_fit, diverged_fit = _predict(layout, model, jnp.asarray(p), f, numerics)
    if bool(diverged_fit):
        problems.append("the fitted model diverges")
    g = np.asarray(lay.natural_jacobian(layout, jnp.asarray(p), model))
    cov = g @ cov_p @ g.T
    se_nat = np.sqrt(np.maximum(np.diag(cov), 0.0))
    values_nat = np.asarray(lay.natural(layout, jnp.asarray(p), model))
    nat_labels = layout.labels()
    if noisy:
        # an SE of zero or none at all: a parameter pinned at the edge of its range (tau_c run to
        # tau_s or to zero, where the map from p stops moving it) or a singular fit
        lost = [lab for lab, se in zip(nat_labels, se_nat, strict=True) if not se > 0]
        if lost:
            problems.append(
                f"no standard error for {', '.join(lost)}: the fit ran to the edge of the parameter's range or "
                "lost it; it is not identifiable from this recording: hold it fixed"
            )

    warnings = []
    if not noisy:
        warnings.append(
            "the model has no noise (ideal sensors, no voluntary force): the standard errors are zero; give the "
            "model the recording's noise (Sensors, VoluntaryForce) for intervals"
        )
    # an entry is weak when its SE exceeds its parameter's own scale: the largest entry of an
    # arm matrix (an off-diagonal entry near zero is not weak for being small), a friction value
    scale = np.concatenate(
        [
            np.full(np.prod(layout.shape(n)), np.abs(v).max() if n in lay.ARM_PARAMETERS else np.nan)
            for n, v in lay.unflatten(layout, values_nat).items()
        ]
    )
    scale = np.where(np.isnan(scale), np.abs(values_nat), scale)
    weak = [
        f"{lab} (SE {s:.3g} against {v:.3g})"
        for lab, v, s, c in zip(nat_labels, values_nat, se_nat, scale, strict=True)
        if s > WEAK_RELATIVE_SE * c
    ]
    if weak:
        warnings.append(
            f"barely identifiable from this recording: {', '.join(weak)}; hold it fixed at a value known from "
            "elsewhere, or record with a perturbation that excites it"
        )
    y = np.concatenate([x, fh], axis=1)
    y_fit = np.asarray(y_fit)
    resid = y - y_fit
    centred = y - y.mean(axis=0)
    vaf = 100.0 * (1.0 - np.sum(resid**2, axis=0) / np.sum(centred**2, axis=0))
    return Identification(
        values=lay.unflatten(layout, values_nat),
        se=lay.unflatten(layout, se_nat),
        covariance=cov,
        labels=nat_labels,
        converged=not problems,
        message="; ".join(problems),
        intervals_reliable=not problems and not warnings,
        warnings=warnings,
        cost=cost,
        iterations=iterations,
        history=history,
        draws=n_draws,
        statistics=dict(zip(statistic_labels(layout), (float(v) for v in b), strict=True)),
        vaf_position=vaf[:2],
        vaf_force=vaf[2:],
        whiteness_p=_ljung_box_p(resid, WHITENESS_LAGS),
        classical=_classical(f, x, fh, model.acquisition, model.period),
        trial=lay.with_values(layout, model, jnp.asarray(p)),
        time_s=time.perf_counter() - t_start,
        forward_s=forward_s,
    )
