"""Parametric identification (docs/model.md section 13): the arm's M, B, K with standard errors, VAF
and a lack-of-fit test.

Each element of a measured impedance is linear in three parameters. In continuous time
``Z_ij(f) = K_ij - w^2 M_ij + j w B_ij`` (``w = 2 pi f``, ``Z = M s^2 + B s + K`` at ``s = j w``,
as ``Arm.impedance``); what a sampled record measures depends on how it was acquired
(``acquisition``, docs/estimation.md section 2):

- ``"delay"`` (the default): a recording of unknown timing: ``exp(-s tau) (M s^2 + B s + K)``,
  a force-channel delay ``tau`` fitted with ``M, B, K``;
- ``"instant"``: samples at the control instants with the force read just before the
  zero-order hold's update (the simulator's default): the mass term carries the hold's
  half-sample lag, ``M s (1 - exp(-s L)) / L`` (derived in docs/estimation.md);
- ``"interval_mean"``: box-car means over each period of position and force: the means
  cancel in ``Z``, so the continuous model holds;
- ``"plain"``: the continuous model as it stands, whatever the timing.

Weighted least squares over the bins. Standard errors from the Welch estimate's own error
model (``se="spectral"``, the default: ``Estimate.error``, correlated bins,
frequency-dependent variance; a sandwich covariance), which also gives a lack-of-fit test
(the residuals against their predicted variance), or from the residuals (``se="residual"``:
one pooled variance, bins independent: the textbook errors, too small for Welch estimates).
The result carries the estimate's diagnostics, and ``ImpedanceFit.warnings`` says in words
when it cannot be trusted.

Single-fit functions; batch with ``jax.vmap``. Differentiable end to end.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import jax.scipy.special as jsp
import numpy as np

from .._checks import as_float64, check_choice, is_concrete, require_x64
from .diagnose import diagnostics_of, unknown_diagnostics
from .estimate import Estimate
from .impedance_fit import ImpedanceFit
from .parametric import ACQUISITIONS, DEFAULT_PERIOD, SE_METHODS, regressors
from .welch import ZError, check_finite

DELAY_ITERATIONS = 8  # Gauss-Newton steps from tau = 0: w tau is small, so 3-4 already converge


def coherence_weights(est: Estimate):
    """Coherence weights ``(F, 2, 2)`` for ``Z = T R^-1`` from an ``Estimate``.

    An H1 row estimated with multiple coherence ``g`` has relative variance proportional to
    ``e = (1 - g) / g`` (the inverse of the common ``g / (1 - g)`` weighting). ``Z_ij``
    inherits errors from row ``i`` of ``T`` (output ``F_h,i``) and from both rows of ``R``
    (outputs ``x``), and first-order relative errors add, so
    ``w_ij = 1 / (e(g_fh,i) + e(g_x,1) + e(g_x,2))``. Zero where a coherence is zero; a
    coherence of 1 counts as ``1 - 1e-12`` so that noise-free records give finite weights.
    Vmappable.
    """
    if not isinstance(est, Estimate):
        raise ValueError(f"coherence_weights needs an Estimate, got {type(est).__name__}")

    def rel_var(g):
        g = jnp.clip(jnp.asarray(g), 0.0, 1.0 - 1e-12)
        return (1.0 - g) / g  # inf where g = 0: the weight below is then 0

    e_fh = rel_var(est.coh_multiple_fh)  # (F, 2), per output i
    e_x = jnp.sum(rel_var(est.coh_multiple_x), axis=-1)  # (F,)
    w = 1.0 / (e_fh + e_x[:, None])  # (F, 2): one weight per row i of Z
    return jnp.broadcast_to(w[:, :, None], w.shape + (2,))


def _as_impedance(z):
    arr = jnp.asarray(z)
    if jnp.issubdtype(arr.dtype, jnp.inexact) and arr.dtype not in (jnp.complex128, jnp.float64):
        raise ValueError(f"Z must be complex128 (or float64), got dtype {arr.dtype}")
    if not jnp.issubdtype(arr.dtype, jnp.number):
        raise ValueError(f"Z must be numeric, got dtype {arr.dtype}")
    arr = arr.astype(jnp.complex128)
    if arr.ndim != 3 or arr.shape[1:] != (2, 2) or arr.shape[0] < 2:
        raise ValueError(f"Z must have shape (F, 2, 2) with F >= 2 frequencies, got {arr.shape}")
    check_finite("Z", arr, where="fit_impedance", index="bin")
    return arr


def _as_weights(weights, n_freq: int, f):
    if weights is None:
        return jnp.ones((n_freq, 2, 2))
    w = as_float64("weights", weights, where="fit_impedance")
    if w.shape == (n_freq,):
        w = jnp.broadcast_to(w[:, None, None], (n_freq, 2, 2))
    elif w.shape != (n_freq, 2, 2):
        raise ValueError(f"weights must have shape (F,) or (F, 2, 2) with F = {n_freq}, got {w.shape}")
    if is_concrete(w) and is_concrete(f):
        wn, fn = np.asarray(w), np.asarray(f)
        if not np.all(np.isfinite(wn)) or np.any(wn < 0):
            raise ValueError("weights must be finite and >= 0")
        for i, j in np.ndindex(2, 2):
            if len(np.unique(fn[wn[:, i, j] > 0])) < 2:
                raise ValueError(f"weights of element ({i}, {j}) must be positive at two or more distinct frequencies")
    return w


def _as_error(error, n_freq: int) -> ZError:
    if not isinstance(error, ZError):
        raise ValueError(f"error must be a ZError (Estimate.error of estimate(..., errors=True)), got {error!r}")
    for name in ("force", "position"):
        shape = jnp.shape(getattr(error, name))
        if shape != (n_freq, 2, 2):
            raise ValueError(f"error.{name} must have shape (F, 2, 2) = ({n_freq}, 2, 2) to match Z, got {shape}")
    if jnp.ndim(error.bin_corr) != 1 or jnp.shape(error.bin_corr)[0] < 1 or jnp.shape(error.dof) != (n_freq,):
        raise ValueError(f"error.bin_corr must have shape (D + 1,) and error.dof shape (F,) = ({n_freq},)")
    if jnp.shape(error.n_eff) != ():
        raise ValueError(f"error.n_eff must be a scalar, got shape {jnp.shape(error.n_eff)}")
    return error


def _sqrt_psd2(a):
    """Hermitian square root of ``(..., 2, 2)`` positive semi-definite matrices (closed form)."""
    det = jnp.real(a[..., 0, 0] * a[..., 1, 1] - a[..., 0, 1] * a[..., 1, 0])
    s = jnp.sqrt(jnp.maximum(det, 0.0))
    t2 = jnp.real(a[..., 0, 0] + a[..., 1, 1]) + 2.0 * s
    ok = t2 > 0
    t = jnp.sqrt(jnp.where(ok, t2, 1.0))
    root = (a + s[..., None, None] * jnp.broadcast_to(jnp.eye(2), a.shape)) / t[..., None, None]
    return jnp.where(ok[..., None, None], root, 0.0)


def _shift(a, d: int):
    """``a[k + d]`` along axis 0, zero outside (``d`` static, either sign)."""
    n = a.shape[0]
    if abs(d) >= n:
        return jnp.zeros_like(a)
    pad = [(0, 0)] * a.ndim
    if d > 0:
        pad[0] = (0, d)
        return jnp.pad(a[d:], pad)
    pad[0] = (-d, 0)
    return jnp.pad(a[: n + d], pad)


def _banded_sum(a, b, rho, fn):
    """``sum_k sum_d rho[|d|] fn(a[k], b[k + d])`` over ``|d| <= D`` (``fn`` elementwise)."""
    total = fn(a, b) * rho[0]
    for d in range(1, min(rho.shape[0], a.shape[0])):
        total = total + rho[d] * (fn(a, _shift(b, d)) + fn(a, _shift(b, -d)))
    return total


def _solve_elements(x, wts, y):
    """Per-element weighted least squares with real parameters: ``theta`` ``(4, 3)`` and the
    normal matrices ``(4, 3, 3)`` for ``y ~ x theta_e`` (``x`` ``(F, 3)``, ``y``, ``wts`` ``(F, 4)``)."""
    a = jnp.real(jnp.einsum("fe,fp,fq->epq", wts, jnp.conj(x), x))
    b = jnp.real(jnp.einsum("fe,fp,fe->ep", wts, jnp.conj(x), y))
    return jnp.linalg.solve(a, b[..., None])[..., 0], a


def _p_value(ratio, nu1, nu2):
    """Upper tail of an F(nu1, nu2) distribution at ``ratio`` (no derivative through the
    degrees of freedom: JAX's betainc has none in its shape parameters)."""
    nu1, nu2 = jax.lax.stop_gradient(nu1), jax.lax.stop_gradient(nu2)
    x = nu2 / (nu2 + nu1 * ratio)
    return jsp.betainc(0.5 * nu2, 0.5 * nu1, jnp.clip(x, 0.0, 1.0))


def fit_impedance(
    Z,
    f=None,
    *,
    weights=None,
    acquisition: str = "delay",
    period: float = DEFAULT_PERIOD,
    se: str = "spectral",
    error: ZError | None = None,
    friction: float | None = None,
) -> ImpedanceFit:
    """Fit ``M, B, K`` to an impedance ``Z(f)`` element by element (docs/model.md section 13).

    Args:
        Z: an ``Estimate`` (``estimate``'s result: its ``Z``, ``f``, ``error`` and
            coherences are used; then ``f`` and ``error`` must be omitted), or an impedance
            [N/m] ``(F, 2, 2)`` complex, indexed ``[output, input]``.
        f: frequencies [Hz] ``(F,)`` of a ``Z`` array, ``>= 0`` with two or more distinct values.
        weights: ``None`` (uniform), an array ``(F,)`` or ``(F, 2, 2)`` of weights ``>= 0``
            (per bin, or per bin and element), or, with an ``Estimate``, ``"uniform"`` or
            ``"coherence"`` (``coherence_weights``).
        acquisition: how the record was sampled, which decides the model of the recorded
            ``Z``: ``"delay"`` (default, for unknown timing: ``exp(-s tau) (M s^2 + B s + K)``
            with the force-channel delay ``tau`` fitted too), ``"instant"`` (samples at the
            control instants, force just before the hold's update: ``M s (1 - exp(-s L)) / L
            + B s + K``), ``"interval_mean"`` (box-car means: ``M s^2 + B s + K``) or
            ``"plain"`` (``M s^2 + B s + K`` whatever the timing). docs/estimation.md section 2.
        period: the hold (control and acquisition) period ``L`` [s] of ``"instant"``, and
            the scale against which a fitted delay is read as the hold's lag (default 1 ms,
            the simulator's; ``1 / fs`` for a recording).
        se: ``"spectral"`` (default): from the estimate's error model (``Estimate.error``,
            or ``error``), a sandwich covariance over correlated bins of unequal variance;
            ``"residual"``: the textbook WLS errors from the residuals, one pooled variance
            per element and independent bins (too small for Welch estimates, whose bins are
            correlated). docs/estimation.md section 3.
        error: a ``ZError`` for a ``Z`` array (with an ``Estimate``, its own ``error``).
        friction: the robot's largest Coulomb joint torque [N m], when known (``None``:
            unknown). It changes no number; with force samples taken at an instant
            (``"instant"``, or a fitted delay that is consistent with the hold's lag) the
            result warns that friction biases M and B there when ``friction > 0``, or, with
            the friction unknown, when the estimate shows stick-slip (``force_excess``); a
            friction of 0 silences that (docs/estimation.md section 3).

    The lack-of-fit fields need an error model (else NaN), whatever ``se``. Solved in closed
    form (``"delay"``: Gauss-Newton on ``tau`` with ``M, B, K`` eliminated, from ``tau = 0``, a
    fixed number of steps), on regressors scaled by the highest frequency.

    Returns an ``ImpedanceFit``; ``fit.summary()`` gives its intervals and warnings as text. Single
    fit; ``jax.vmap`` batches it (shape checks are static; value checks, e.g. NaN in ``Z``,
    run only on concrete inputs). Differentiable in ``Z``, ``f``, ``weights`` and ``error``;
    standard errors have no finite gradient on noise-free data (``sqrt`` at 0).
    """
    require_x64("fit_impedance")
    check_choice("acquisition", acquisition, ACQUISITIONS)
    check_choice("se", se, SE_METHODS)
    z, f, w, error, diagnostics = _inputs(Z, f, weights, error, se)
    if acquisition in ("instant", "delay"):
        period = _check_period(period)
    if friction is not None and not 0 <= friction < math.inf:
        raise ValueError(f"friction must be a Coulomb torque >= 0 N m (or None: unknown), got {friction!r}")
    diagnostics = diagnostics._replace(
        friction=jnp.asarray(jnp.nan if friction is None else friction, dtype=jnp.float64),
        instant_samples=jnp.asarray({"instant": 1.0, "delay": jnp.nan}.get(acquisition, 0.0)),
        period=jnp.asarray(period, dtype=jnp.float64),
    )
    return _general_fit_compiled(z, f, w, acquisition, period, se, error, diagnostics)


def _inputs(Z, f, weights, error, se):
    """Checked ``(z, f, w, error, diagnostics)`` from ``fit_impedance``'s arguments."""
    if isinstance(Z, Estimate):
        if f is not None:
            raise ValueError("pass an Estimate alone, or Z and f; not an Estimate and f")
        if error is not None:
            raise ValueError("pass an Estimate alone (its own error is used), or Z, f and error")
        est, Z, f, error = Z, Z.Z, Z.f, Z.error
        if isinstance(weights, str):
            if weights not in ("uniform", "coherence"):
                raise ValueError(f"unknown weights {weights!r}; allowed: 'uniform', 'coherence'")
            weights = None if weights == "uniform" else coherence_weights(est)
        diagnostics = diagnostics_of(est)
    else:
        if isinstance(weights, str):
            raise ValueError(f"weights={weights!r} needs an Estimate as the first argument; with Z pass an array")
        diagnostics = unknown_diagnostics(jnp.nan if error is None else getattr(error, "n_eff", jnp.nan))
    if f is None:
        raise ValueError("f (the frequencies of Z [Hz], shape (F,)) is required with a Z array")
    if se == "spectral" and error is None:
        raise ValueError(
            'se="spectral" (the default) needs an error model: fit the Estimate of estimate(...) (it carries one '
            'unless errors=False), or pass error=Estimate.error; se="residual" gives the textbook errors instead'
        )
    z = _as_impedance(Z)
    n_freq = z.shape[0]
    f = as_float64("f", f, where="fit_impedance")
    if f.shape != (n_freq,):
        raise ValueError(f"f must have shape (F,) = ({n_freq},) to match Z {z.shape}, got {f.shape}")
    check_finite("f", f, where="fit_impedance", index="bin")
    if is_concrete(f):
        fn = np.asarray(f)
        if np.any(fn < 0) or len(np.unique(fn)) < 2:
            raise ValueError("f must be finite, >= 0 Hz and hold at least two distinct frequencies")
    w = _as_weights(weights, n_freq, f)
    return z, f, w, None if error is None else _as_error(error, n_freq), diagnostics


def _check_period(period) -> float:
    try:
        period = float(period)
    except (TypeError, ValueError):
        raise ValueError(f"period must be a number (the hold period [s]), got {period!r}") from None
    if not 0 < period < math.inf:
        raise ValueError(f"period must be a finite hold period > 0 s, got {period!r}")
    return period


def _general_fit(z, f, w, acquisition, period, se, error, diagnostics) -> ImpedanceFit:
    """The weighted least-squares fit of the recorded model, its covariance and lack of fit."""
    n_freq = z.shape[0]
    omega = 2.0 * jnp.pi * f
    w0 = jnp.max(omega)
    scale = jnp.stack([jnp.ones(()), w0**2, w0])  # K, M, B: the fit solves for K, w0^2 M, w0 B
    x = regressors(omega, acquisition, period) / scale[None]  # (F, 3), entries O(1)
    v = omega / w0
    y = z.reshape(n_freq, 4)  # element e = 2 i + j
    wts = w.reshape(n_freq, 4)
    delay = acquisition == "delay"
    tau = _delay_search(x, v, y, wts) if delay else jnp.zeros(())  # w0 * delay
    phase = jnp.exp(-1j * v * tau)[:, None]  # (F, 1)
    theta, _ = _solve_elements(x, wts, y * jnp.conj(phase))
    model = (x @ theta.T) * phase  # (F, 4): the recorded Z as fitted
    r = y - model
    fitted = (wts > 0).astype(r.real.dtype)  # the VAF of the bins fitted (all, unless a weight is 0)
    jac, normal, gk = _sensitivities(x, v, wts, phase, model, delay)
    spectral = None if error is None else _spectral_covariance(gk, error)
    if se == "residual":
        cov, dof, par_dof = _residual_covariance(r, wts, jac, normal)
    else:
        cov, dof, par_dof = _spectral_dof(spectral, error)
    sd = jnp.sqrt(jnp.diag(cov))
    th = theta.reshape(2, 2, 3)
    sd_e = sd[:12].reshape(2, 2, 3)
    fit = ImpedanceFit(
        mass=th[..., 1] / w0**2,
        damping=th[..., 2] / w0,
        stiffness=th[..., 0],
        mass_se=sd_e[..., 1] / w0**2,
        damping_se=sd_e[..., 2] / w0,
        stiffness_se=sd_e[..., 0],
        vaf=100.0
        * (1.0 - jnp.sum(fitted * jnp.abs(r) ** 2, axis=0) / jnp.sum(fitted * jnp.abs(y) ** 2, axis=0)).reshape(2, 2),
        vaf_overall=100.0 * (1.0 - jnp.sum(fitted * jnp.abs(r) ** 2) / jnp.sum(fitted * jnp.abs(y) ** 2)),
        dof=dof,
        **_no_delay_no_test(),
        diagnostics=diagnostics,
    )
    if delay:
        fit = fit._replace(delay=tau / w0, delay_se=sd[12] / w0, delay_dof=par_dof[12])
    if error is None:
        return fit
    cov_spec, yq, _, rho, root = spectral
    return fit._replace(**_lack_of_fit(r, wts, jac, root, gk, yq, cov_spec, rho, error.dof))


def _no_delay_no_test() -> dict:
    """The delay and lack-of-fit fields of a fit without either: 0 delay, NaN test."""
    nan = jnp.full((), jnp.nan)
    return dict(
        delay=jnp.zeros(()),
        delay_se=jnp.zeros(()),
        delay_dof=nan,
        lack_of_fit=jnp.full((2, 2), jnp.nan),
        lack_of_fit_p=jnp.full((2, 2), jnp.nan),
        lack_of_fit_overall=nan,
        lack_of_fit_p_overall=nan,
    )


# one compiled program per shape and model, not a few hundred op-by-op ones (the banded sums)
_general_fit_compiled = jax.jit(_general_fit, static_argnums=(3, 4, 5))


def _delay_search(x, v, y, wts):
    """Gauss-Newton on the scaled delay ``w0 tau`` with ``M, B, K`` eliminated (variable
    projection), from 0, ``DELAY_ITERATIONS`` steps."""
    tau = jnp.zeros(())
    for _ in range(DELAY_ITERATIONS):
        rot = jnp.exp(1j * v * tau)[:, None]
        theta, a = _solve_elements(x, wts, y * rot)
        r = y * rot - x @ theta.T
        dy = 1j * v[:, None] * y * rot  # d(y rot)/d tau
        c = jnp.linalg.solve(a, jnp.real(jnp.einsum("fe,fp,fe->ep", wts, jnp.conj(x), dy))[..., None])[..., 0]
        dyp = dy - x @ c.T  # its part that M, B, K cannot absorb
        tau = tau - jnp.sum(wts * jnp.real(jnp.conj(dyp) * r)) / jnp.sum(wts * jnp.abs(dyp) ** 2)
    return tau


def _sensitivities(x, v, wts, phase, model, delay: bool):
    """The recorded model's Jacobian ``(F, 4, P)`` in the parameters [theta_e (3 each) ...,
    tau], the normal matrix ``(P, P)`` and the gain ``gk`` ``(F, P, 4)``: the parameters'
    error is ``Re sum_k gk[k] dZ[k]``."""
    n_freq = x.shape[0]
    n_par = 13 if delay else 12
    eye4 = jnp.eye(4)
    jac = (eye4[None, :, :, None] * (x * phase)[:, None, None, :]).reshape(n_freq, 4, 12)
    if delay:
        jac = jnp.concatenate([jac, (-1j * v[:, None] * model)[..., None]], axis=-1)
    normal = jnp.real(jnp.einsum("fe,fep,feq->pq", wts, jnp.conj(jac), jac))
    g = jnp.linalg.solve(normal, jnp.swapaxes(jnp.conj(jac) * wts[..., None], 0, 2).reshape(n_par, 4 * n_freq))
    g = jnp.swapaxes(g.reshape(n_par, 4, n_freq), 0, 2).reshape(n_freq, 4, n_par)
    return jac, normal, jnp.swapaxes(g, -1, -2)


def _spectral_covariance(gk, error: ZError):
    """The parameters' covariance under the estimate's error model, with the pieces the
    lack-of-fit test and the degrees of freedom reuse: ``(cov, yq, root, rho)``."""
    n_freq = gk.shape[0]
    root = jnp.einsum("fac,fbd->fabcd", _sqrt_psd2(error.force), _sqrt_psd2(error.position)).reshape(n_freq, 4, 4)
    rho = jnp.asarray(error.bin_corr)
    q = gk @ root  # (F, P, 4)
    yq = _banded_sum(q, q, rho, lambda a, b: b)  # sum_d rho q[k + d]
    cov = 0.5 * jnp.real(jnp.einsum("fpm,fqm->pq", yq, jnp.conj(q)))
    return 0.5 * (cov + cov.T), yq, q, rho, root


def _spectral_dof(spectral, error: ZError):
    """``(cov, dof (2, 2), per-parameter dof)`` of ``se="spectral"``. Satterthwaite: the
    variance is a sum of bins' residual spectra, each with ``error.dof`` degrees of freedom
    and correlated between bins as ``bin_corr^2``."""
    cov, yq, q, rho, _ = spectral
    share = jnp.abs(0.5 * jnp.real(jnp.einsum("fpm,fpm->fp", yq, jnp.conj(q))))  # (F, P)
    rel = share / jnp.sqrt(error.dof)[:, None]  # each share's sd is sqrt(2 / dof) of it
    spread = _banded_sum(rel, rel, rho**2, lambda a, b: a * b)
    par_dof = jnp.sum(share, axis=0) ** 2 / jnp.sum(spread, axis=0)
    return cov, jnp.min(par_dof[:12].reshape(4, 3), axis=-1).reshape(2, 2), par_dof


def _residual_covariance(r, wts, jac, normal):
    """``(cov, dof (2, 2), per-parameter dof)`` of ``se="residual"``: one pooled residual
    variance per element, bins independent."""
    n_par = normal.shape[0]
    dof_e = 2.0 * jnp.sum(wts > 0, axis=0) - 3.0
    s2 = jnp.sum(wts * jnp.abs(r) ** 2, axis=0) / dof_e  # (4,)
    meat = jnp.real(jnp.einsum("fe,fep,feq->pq", wts * s2[None], jnp.conj(jac), jac))
    cov = jnp.linalg.solve(normal, jnp.linalg.solve(normal, meat).T)
    par_dof = jnp.concatenate([jnp.repeat(dof_e, 3), jnp.full((n_par - 12,), jnp.min(dof_e))])
    return cov, dof_e.reshape(2, 2), par_dof


def _lack_of_fit(r, wts, jac, root, gk, yq, cov, rho, dof_bin) -> dict:
    """Residual sum of squares against its expectation under the error model: an F test."""
    t_e = jnp.sum(wts * jnp.abs(r) ** 2, axis=0)  # (4,)
    var_e = jnp.real(jnp.einsum("fem,fem->fe", root, jnp.conj(root)))  # (F, 4): Var dZ_e
    # E|r|^2 = Var dZ - 2 Re E[conj(dZ) J dp] + E|J dp|^2 (dp: the parameters' error)
    cross = jnp.real(jnp.einsum("fep,fpm,fem->fe", jac, yq, jnp.conj(root)))
    lev = jnp.real(jnp.einsum("fep,pq,feq->fe", jac, cov, jnp.conj(jac)))
    e_e = jnp.sum(wts * (var_e - cross + lev), axis=0)

    def pair(a, b):  # |(L_k L_k'^H)[e, e']|^2 weighted, for every e, e'
        c = jnp.einsum("fem,fgm->feg", a[0], jnp.conj(b[0]))
        return a[1][:, :, None] * b[1][:, None, :] * jnp.abs(c) ** 2

    rw = (root, wts)
    total = pair(rw, rw) * rho[0] ** 2
    for d in range(1, min(rho.shape[0], r.shape[0])):
        for s in (d, -d):
            total = total + rho[d] ** 2 * pair(rw, (_shift(root, s), _shift(wts, s)))
    total = jnp.sum(total, axis=0)  # (4, 4)
    var_t_e = jnp.diagonal(total)
    var_t = jnp.sum(total)
    a_k = wts * var_e  # bins' shares of the expectation, for the denominator's dof
    rel = a_k / jnp.sqrt(dof_bin)[:, None]
    nu2_e = jnp.sum(a_k, axis=0) ** 2 / jnp.sum(_banded_sum(rel, rel, rho**2, lambda a, b: a * b), axis=0)
    a_all, rel_all = jnp.sum(a_k, axis=1), jnp.sum(rel, axis=1)
    nu2 = jnp.sum(a_all) ** 2 / jnp.sum(_banded_sum(rel_all, rel_all, rho**2, lambda a, b: a * b))
    ratio_e = t_e / e_e
    ratio = jnp.sum(t_e) / jnp.sum(e_e)
    nu1_e = 2.0 * e_e**2 / var_t_e
    nu1 = 2.0 * jnp.sum(e_e) ** 2 / var_t
    return dict(
        lack_of_fit=ratio_e.reshape(2, 2),
        lack_of_fit_p=_p_value(ratio_e, nu1_e, nu2_e).reshape(2, 2),
        lack_of_fit_overall=ratio,
        lack_of_fit_p_overall=_p_value(ratio, nu1, nu2),
    )
