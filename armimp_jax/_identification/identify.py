"""Identify an arm (and the robot's friction) through the closed-loop model: ``identify``.

Given the commanded ``F_Delta`` and the recorded hand position and force, estimate named
parameters of a trial by fitting the simulated closed loop to the time-domain recording,
with exact Jacobians from JAX and optimistix's Levenberg-Marquardt (``model_fit.py``):

1. **Output error** from the starting values on the record's first 5 s: the residual is
   the recording minus the noise-free simulation, each channel (two position axes, two
   force axes) divided by its standard deviation in the recording.
2. The whole record from there: output error again (``noise_order=0``, the default), or
   **prediction error** with a VAR noise model fitted to stage 1's residuals
   (``noise_order > 0``; ``model_fit.NoiseModel``), or output error **weighted to a band**
   of frequencies (``band=(low, high)`` Hz; ``model_fit.Band``), then Gauss-Newton steps
   while they lower the cost.
3. **Covariance** by the linearised parametric bootstrap: recordings re-simulated from the
   fitted model with the trial's own noise (sensors and voluntary force) and pushed
   through one Gauss-Newton step. Their mean is the estimator's first-order bias
   (``bias``, reported, not subtracted). The textbook ``s^2 (J^T J)^-1`` is reported
   alongside (``se_textbook``) for comparison only.
4. **Linearity check.** The bootstrap is the estimator's spread only where the fit is
   linear in the noise over a few SEs. On ``LINEARITY_DRAWS`` re-simulated recordings, one
   more Gauss-Newton step from their one-step estimates; an RMS move above
   ``LINEARITY_LIMIT`` SE sets ``intervals_reliable=False`` with a warning. Measured cause
   when it fires: with the person's force in the loop the cost is far from quadratic over
   a few SEs (its curvature along the Gauss-Newton step was 0.6 of ``J^T J``'s, with
   negative curvature in some directions), so re-fits spread up to 3x wider than one
   linear step says (docs/identification.md).

Why output error by default: with the person's force in the loop, the noise-free
simulation is not the mean of the noisy closed loop (the force dithers the friction), so
both fits carry a bias; whitening makes the estimate several times more precise but not
less biased, and the bias then dominates its intervals (docs/identification.md).

Convergence is judged at the end, not taken from the solver: the fit is called converged
when one more Gauss-Newton step would move every parameter by less than
``CONVERGED_FRACTION`` of its standard error and the fitted model does not diverge.
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
from . import layout as lay
from . import model_fit as mf
from .model_fit import IDENTIFY_NUMERICS

CONVERGED_FRACTION = 0.1  # a last Gauss-Newton step below this many standard errors: converged
# The intervals rest on the fit being linear in the noise over a few SEs. Checked on
# LINEARITY_DRAWS re-simulated recordings: one more Gauss-Newton step from their one-step
# estimates; an RMS move above LINEARITY_LIMIT SE says the estimator spreads wider than the
# bootstrap shows (docs/identification.md, section 5).
LINEARITY_DRAWS = 4
LINEARITY_LIMIT = 0.5
IDENTIFIABLE_RATIO = 1e-6  # smallest / largest singular value of the column-scaled Jacobian
# Solver tolerances on the scaled parameters, whose unit moves the residual's norm by one (a
# standard error is several units here): stage 1 only brings the fit near, stage 2 refines.
# Tighter ones only make the solver crawl through the noise's roughness of the cost.
OUTPUT_ERROR_TOL = 1e-2
PREDICTION_ERROR_TOL = 1e-3
POLISH_STEPS = 3
OUTPUT_ERROR_SAMPLES = 5000  # stage 1 fits the record's first 5 s
WHITENESS_LAGS = 20  # Ljung-Box lags of the whitened residual
MIN_SAMPLES = 1000
CHANNELS = ("x1", "x2", "fh1", "fh2")


@dataclasses.dataclass(frozen=True)
class Identification:
    """The result of ``identify`` (host values).

    Attributes:
        values: ``{name: array}`` the estimates, in each parameter's units and shape
            (``(2, 2)`` arm matrices indexed ``[output, input]``, ``(2,)`` friction per joint).
        se: ``{name: array}`` their standard errors (bootstrap), same units and shapes.
        se_textbook: the textbook Gauss-Newton ``s^2 (J^T J)^-1`` errors of the whitened fit
            (white, input-independent residuals assumed; for comparison).
        bias: ``{name: array}`` the bootstrap's mean step: the estimator's first-order bias
            at the estimate (reported, not subtracted).
        covariance: ``(n, n)`` covariance of every entry, in the order of ``labels``.
        labels: names of the entries, e.g. ``"arm.mass[0,1]"``.
        converged: whether the fit is sound (see the module docstring); ``message`` says why not.
        intervals_reliable: converged, and the linearity check passed: the SEs describe the
            estimator's spread. ``False``: read ``warnings``; the intervals are then too narrow.
        linearity: the check's statistic: the largest RMS (over ``LINEARITY_DRAWS``
            re-simulated recordings) of a second Gauss-Newton step, in SEs (0 without noise).
        warnings: plain sentences on what not to trust.
        cost: final prediction-error cost ``|r_w|^2 / 2`` (whitened residual).
        iterations: Levenberg-Marquardt steps, both stages.
        vaf_position, vaf_force: ``(2,)`` variance of the recorded ``x`` and ``F_h`` accounted
            for by the fitted model's noise-free simulation [%], per axis.
        whiteness_p: ``(4,)`` Ljung-Box p-values of the whitened residual (x1, x2, fh1, fh2;
            ``WHITENESS_LAGS`` lags): small values say the noise model left structure.
        classical: the Welch FRF + ``fit_impedance`` answer from the same recording
            (``None`` when the record is too short for two Welch segments).
        trial: the model with the estimates in place.
        time_s: wall time of the call [s]; forward_s: one noise-free simulation of the
            record, timed in the call [s] (the unit of ``time_s / forward_s``).
    """

    values: dict
    se: dict
    se_textbook: dict
    bias: dict
    covariance: np.ndarray
    labels: list
    converged: bool
    message: str
    intervals_reliable: bool
    linearity: float
    warnings: list
    cost: float
    iterations: int
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
        """A few lines: convergence, then each parameter as value +- SE."""
        lines = [("converged" if self.converged else "NOT CONVERGED: " + self.message)]
        lines += ["WARNING: " + w for w in self.warnings]
        for name in self.values:
            v, s = np.asarray(self.values[name]), np.asarray(self.se[name])
            lines.append(f"{name}: {np.array2string(v, precision=4)} +- {np.array2string(s, precision=4)}")
        return "\n".join(lines)


def _check_recording(f, x, fh, where: str):
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


@functools.partial(jax.jit, static_argnames=("layout", "numerics"))
def _predict(layout, model, p, f, numerics):
    return mf.predict(layout, model, p, f, numerics)


@functools.partial(jax.jit, static_argnames=("layout", "numerics"))
def _residual_jacobian(layout, model, p, f, y, scale, noise, numerics):
    return mf.residual_jacobian(layout, model, p, f, y, scale, noise, numerics)


@functools.partial(jax.jit, static_argnames=("layout", "numerics", "max_steps", "tol"))
def _lm(layout, model, p0, colscale, f, y, scale, noise, numerics, max_steps, tol):
    return mf.levenberg_marquardt(layout, model, p0, colscale, f, y, scale, noise, numerics, max_steps, tol)


@functools.partial(jax.jit, static_argnames=("layout", "numerics"))
def _noisy(layout, model, p, f, keys, numerics):
    return mf.noisy_outputs(layout, model, p, f, keys, numerics)


_bootstrap_steps = jax.jit(mf.bootstrap_steps)


_noise_model = jax.jit(mf.fit_noise_model, static_argnames="order")


def _fit_stage(layout, model, p, f, y, scale, noise, numerics, max_steps, tol, labels):
    _, jac = _residual_jacobian(layout, model, p, f, y, scale, noise, numerics)
    norms = np.sqrt(np.sum(np.asarray(jac) ** 2, axis=0))  # the solver steps in units of 1 / norm
    dead = [labels[i] for i in np.flatnonzero(~(norms > 0))]
    if dead:
        raise ValueError(f"identify: the recording does not depend on {dead} at the start (zero sensitivity)")
    return _lm(layout, model, p, jnp.asarray(1.0 / norms), f, y, scale, noise, numerics, max_steps, tol)


def _ljung_box_p(e, lags: int):
    e = e - e.mean(axis=0)
    n = e.shape[0]
    denom = np.sum(e * e, axis=0)
    q = np.zeros(e.shape[1])
    for k in range(1, lags + 1):
        rho = np.sum(e[k:] * e[:-k], axis=0) / denom
        q += rho**2 / (n - k)
    return scipy.stats.chi2.sf(n * (n + 2) * q, lags)


def _classical(f, x, fh, acquisition):
    n = f.shape[0]
    nperseg = min(8192, 2 ** int(math.floor(math.log2(n / 2))))
    try:
        est = estimate(f, x, fh, nperseg=nperseg, noverlap=3 * nperseg // 4)
    except ValueError:
        return None
    return fit_impedance(est, acquisition=acquisition if acquisition in ("instant", "interval_mean") else "plain")


def _internal_labels(layout):
    """Names of ``p``'s entries as a reader knows them (``"arm.damping[0,1]"``, ``"friction.tau_c[1]"``)."""
    out = []
    for i, name in enumerate(layout.names):
        if layout.symmetric[i]:
            out += [f"{name}[{k}]" for k in ("0,0", "0,1", "1,1")]
        elif name in lay.ARM_PARAMETERS:
            out += [f"{name}[{r},{c}]" for r in range(2) for c in range(2)]
        else:
            out += [f"{name}[{j}]" for j in range(2)]
    return out


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
    bootstrap: int = 100,
    noise_order: int = 0,
    band=None,
    max_steps: int = 100,
) -> Identification:
    """Estimate parameters of ``model`` from a recording, through the closed-loop simulation.

    Args:
        model: a ``Trial`` holding every fixed setting (robot, controller, acquisition,
            sensors' and voluntary force's noise levels) and the starting values of the free
            parameters.
        f: the commanded perturbation ``F_Delta`` ``(N, 2)`` [N].
        x, fh: the recorded hand position [m] and force [N], ``(N, 2)`` each.
        free: names of the parameters to estimate, from ``"arm.mass"``, ``"arm.damping"``,
            ``"arm.stiffness"`` (full 2x2), ``"friction.tau_c"``, ``"friction.tau_s"``,
            ``"friction.sigma0"``, ``"friction.sigma1"``, ``"friction.sigma2"`` (per joint).
        symmetric: free arm matrices to constrain symmetric (3 numbers instead of 4).
        numerics: integration settings (default ``IDENTIFY_NUMERICS``, ``GradedARK4`` at 4
            substeps: converged at every friction in [0, 4] N m).
        key: ``jax.random`` key of the bootstrap's noise draws (default ``key(0)``: the
            result is deterministic). A model without noise (ideal sensors, no voluntary
            force) has nothing to re-simulate: its SEs are then the textbook ones.
        bootstrap: noisy re-simulations behind the covariance (>= 10; SEs good to about
            ``1 / sqrt(2 bootstrap)``).
        noise_order: lags of the VAR noise model (0: output error only, no whitening).
        band: ``(low, high)`` [Hz]: weight the residual to this band of frequencies (e.g.
            ``(3, 25)`` leaves out the person's slow force below 2 Hz and the sensors' noise
            above the perturbation's band); ``None`` (default) weighs every frequency.
            Not together with ``noise_order``.
        max_steps: Levenberg-Marquardt steps per stage.

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
    f, x, fh = _check_recording(f, x, fh, "identify")
    bootstrap = check_int("bootstrap", bootstrap, minimum=10)
    noise_order = check_int("noise_order", noise_order, minimum=0)
    band = mf.check_band(band, f.shape[0], "identify")
    if band is not None and noise_order:
        raise ValueError(f"identify: pass band or noise_order, not both (got noise_order={noise_order})")
    max_steps = check_int("max_steps", max_steps, minimum=1)
    numerics = IDENTIFY_NUMERICS if numerics is None else numerics
    if not isinstance(numerics, Numerics):
        raise ValueError(f"identify: numerics must be a Numerics, got {type(numerics).__name__}")
    key = jax.random.key(0) if key is None else key
    p0 = lay.pack(layout, model)
    labels = _internal_labels(layout)

    y = jnp.concatenate([x, fh], axis=1)
    scale = jnp.std(y, axis=0)
    flat = [CHANNELS[i] for i in np.flatnonzero(~(np.asarray(scale) > 0))]
    if flat:
        raise ValueError(f"identify: the recorded channel(s) {flat} are constant; nothing to fit")
    _, diverged = _predict(layout, model, p0, f, numerics)
    if bool(diverged):
        start = {n: np.asarray(v).tolist() for n, v in lay.split(layout, p0, model).items()}
        raise ValueError(f"identify: the model diverges at the starting values {start}; choose another start")
    t0 = time.perf_counter()
    jax.block_until_ready(_predict(layout, model, p0, f, numerics))
    forward_s = time.perf_counter() - t0

    # 1. output error, noise-free predictor, on the record's first seconds: brings a generic
    # start near the answer at a fraction of the cost of the whole record
    n_pre = min(f.shape[0], OUTPUT_ERROR_SAMPLES)
    p, ok, steps = _fit_stage(
        layout, model, p0, f[:n_pre], y[:n_pre], scale, None, numerics, max_steps, OUTPUT_ERROR_TOL, labels
    )
    iterations = int(steps)
    # 2. the whole record: prediction error with a VAR noise model of stage 1's residuals
    # (output error again when noise_order is 0)
    noise = band
    if noise_order:
        noise = _noise_model((_predict(layout, model, p, f, numerics)[0] - y) / scale[None, :], order=noise_order)
    if noise is not None or n_pre < f.shape[0] or not bool(ok):
        p, ok, steps = _fit_stage(
            layout, model, p, f, y, scale, noise, numerics, max_steps, PREDICTION_ERROR_TOL, labels
        )
        iterations += int(steps)
    # 3. Gauss-Newton steps while they lower the cost (the solver stops at a tolerance far
    # above round-off; these reach it on noise-free recordings), then the linearised
    # bootstrap at the estimate for the covariance and the first-order bias
    r, jac = _residual_jacobian(layout, model, p, f, y, scale, noise, numerics)
    for _ in range(POLISH_STEPS):
        gn_map = mf.gauss_newton_map(jac)
        newton = -np.asarray(gn_map) @ np.asarray(r)
        r_new, jac_new = _residual_jacobian(layout, model, p + newton, f, y, scale, noise, numerics)
        if not float(r_new @ r_new) < float(r @ r):
            break
        p, r, jac = p + newton, r_new, jac_new
        iterations += 1
    gn_map = mf.gauss_newton_map(jac)
    newton = -np.asarray(gn_map) @ np.asarray(r)
    y_fit, diverged_fit = _predict(layout, model, p, f, numerics)
    r, jac = np.asarray(r), np.asarray(jac)
    dof = max(r.size - p.shape[0], 1)
    # identifiability: a direction of p the recording hardly sees (J's columns scaled to unit
    # norm, smallest singular value against the largest); pinv keeps the rest well defined
    unit = jac / np.maximum(np.linalg.norm(jac, axis=0), np.finfo(float).tiny)
    _, sv, vt = np.linalg.svd(unit, full_matrices=False)
    weak = sv[-1] < IDENTIFIABLE_RATIO * sv[0]
    weakest = labels[int(np.argmax(np.abs(vt[-1])))]
    cov_textbook = float(r @ r) / dof * np.linalg.pinv(jac.T @ jac)
    if model.sensors.ideal and model.voluntary is None:  # no noise model to re-simulate: textbook
        steps_b, boot_diverged, cov_p, ys = np.zeros((2, p.shape[0])), False, cov_textbook, None
    else:
        ys, boot_diverged = _noisy(layout, model, p, f, jax.random.split(key, bootstrap), numerics)
        steps_b = np.asarray(_bootstrap_steps(ys, y_fit, scale, noise, gn_map))
        cov_p = np.cov(steps_b.T, ddof=1).reshape(p.shape[0], p.shape[0])
    se_p = np.sqrt(np.diag(cov_p))
    linearity = 0.0
    if ys is not None:
        # one more Gauss-Newton step on a few re-simulated recordings, from their one-step
        # estimates: the bootstrap's spread is the estimator's only where this step is small
        second = []
        for b in range(min(LINEARITY_DRAWS, bootstrap)):
            p_b = p + jnp.asarray(steps_b[b])
            r_b, jac_b = _residual_jacobian(layout, model, p_b, f, ys[b], scale, noise, numerics)
            second.append(-np.asarray(mf.gauss_newton_map(jac_b)) @ np.asarray(r_b))
        rms = np.sqrt(np.mean(np.square(second), axis=0)) / se_p
        linearity = float(np.max(rms))
        worst_linear = labels[int(np.argmax(rms))]
    g = np.asarray(lay.natural_jacobian(layout, p, model))
    cov = g @ cov_p @ g.T
    se_nat = np.sqrt(np.diag(cov))
    se_tb = np.sqrt(np.diag(g @ cov_textbook @ g.T))
    problems = []
    if bool(diverged_fit):
        problems.append("the fitted model diverges")
    if bool(boot_diverged):
        problems.append("some noisy re-simulations of the fitted model diverged")
    # (a floor at round-off, for noise-free recordings whose SEs are round-off too)
    settled = np.abs(newton) <= np.maximum(CONVERGED_FRACTION * se_p, 1e-9 * (1.0 + np.abs(np.asarray(p))))
    if not np.all(settled):
        worst = int(np.nanargmax(np.abs(newton) / se_p))
        problems.append(
            f"one more Gauss-Newton step would still move {labels[worst]} by "
            f"{abs(newton[worst]) / se_p[worst]:.2g} SE (solver {'converged' if bool(ok) else 'stopped'} "
            f"after {int(steps)} steps)"
        )

    warnings = []
    if weak:
        warnings.append(
            f"{weakest} is barely identifiable from this recording (the Jacobian's columns span "
            f"{sv[0] / sv[-1]:.2g} to 1 in scale): its value and SE are not to be trusted; hold it fixed "
            f"or record with a perturbation that excites it"
        )
    if not linearity <= LINEARITY_LIMIT:  # NaN included
        warnings.append(
            f"intervals unreliable: on re-simulated recordings one more Gauss-Newton step still moves "
            f"{worst_linear} by {linearity:.2g} SE (RMS over {min(LINEARITY_DRAWS, bootstrap)} draws; limit "
            f"{LINEARITY_LIMIT}): the fit is nonlinear at this noise level and its estimates spread wider than "
            f"the SEs say; a larger perturbation or a quieter recording (less voluntary force) helps"
        )
    e_w = np.asarray(r).reshape(-1, 4)
    resid = np.asarray(y) - np.asarray(y_fit)
    centred = np.asarray(y) - np.asarray(y).mean(axis=0)
    vaf = 100.0 * (1.0 - np.sum(resid**2, axis=0) / np.sum(centred**2, axis=0))
    return Identification(
        values=lay.unflatten(layout, np.asarray(lay.natural(layout, p, model))),
        se=lay.unflatten(layout, se_nat),
        se_textbook=lay.unflatten(layout, se_tb),
        bias=lay.unflatten(layout, g @ steps_b.mean(axis=0)),
        covariance=cov,
        labels=layout.labels(),
        converged=not problems,
        message="; ".join(problems),
        intervals_reliable=not problems and not warnings,
        linearity=linearity,
        warnings=warnings,
        cost=0.5 * float(r @ r),
        iterations=iterations,
        vaf_position=vaf[:2],
        vaf_force=vaf[2:],
        whiteness_p=_ljung_box_p(np.asarray(e_w), WHITENESS_LAGS),
        classical=_classical(f, x, fh, model.acquisition),
        trial=lay.with_values(layout, model, p),
        time_s=time.perf_counter() - t_start,
        forward_s=forward_s,
    )
