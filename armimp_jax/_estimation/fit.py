"""Parametric identification (docs/model.md section 13): the arm's M, B, K with standard errors, VAF
and a lack-of-fit test.

Each element of a measured impedance is linear in three parameters. In continuous time
``Z_ij(f) = K_ij - w^2 M_ij + j w B_ij`` (``w = 2 pi f``, ``Z = M s^2 + B s + K`` at ``s = j w``,
as ``Arm.impedance``); what a sampled record measures depends on how it was acquired
(``acquisition``, docs/estimation.md section 2):

- ``"plain"``: the continuous model as it stands (the default, today's fit);
- ``"instant"``: samples at the control instants with the force read just before the
  zero-order hold's update (the simulator's default): the mass term carries the hold's
  half-sample lag, ``M s (1 - exp(-s L)) / L`` (derived in docs/estimation.md);
- ``"interval_mean"``: box-car means over each period of position and force: the means
  cancel in ``Z``, so the continuous model holds;
- ``"delay"``: a lab's recording of unknown timing: ``exp(-s tau) (M s^2 + B s + K)``, a
  force-channel delay ``tau`` fitted with ``M, B, K``.

Weighted least squares over the bins. Standard errors either from the residuals
(``se="residual"``: one pooled variance, bins independent; today's default) or from the
Welch estimate's own error model (``se="spectral"``: ``Estimate.error``, correlated bins,
frequency-dependent variance; a sandwich covariance), which also gives a lack-of-fit test
(the residuals against their predicted variance). ``fit_warnings`` says in words when the
result cannot be trusted.

Single-fit functions; batch with ``jax.vmap``. Differentiable end to end.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import jax.scipy.special as jsp
import numpy as np

from .._checks import as_float64, check_choice, is_concrete, require_x64
from .._simulate import CONTROL_PERIOD
from .welch import Estimate, ZError, check_finite

ACQUISITIONS = ("plain", "instant", "interval_mean", "delay")
SE_METHODS = ("residual", "spectral")
DELAY_ITERATIONS = 8  # Gauss-Newton steps from tau = 0: w tau is small, so 3-4 already converge
ELEMENTS = ((0, 0), (0, 1), (1, 0), (1, 1))


class ImpedanceFit(NamedTuple):
    """``M, B, K`` fitted to an impedance, with standard errors, %VAF and lack of fit (a pytree).

    ``mass`` [kg], ``damping`` [N s/m], ``stiffness`` [N/m], each ``(2, 2)`` indexed
    ``[output, input]`` like ``Z``, and their standard errors ``mass_se``, ``damping_se``,
    ``stiffness_se`` (same units and shapes). ``vaf`` ``(2, 2)`` and ``vaf_overall`` (scalar):
    variance accounted for [%], ``100 (1 - sum |Z - Z_fit|^2 / sum |Z|^2)`` per element and
    over all elements, ``Z_fit`` the model of the recorded ``Z`` (its acquisition included).
    ``dof`` ``(2, 2)``: degrees of freedom of the standard errors (``se="residual"``: ``2 F_w
    - 3``, ``F_w`` bins with positive weight; ``se="spectral"``: the smallest of the
    element's three Satterthwaite values); a two-sided 95% interval is
    ``value +- t_0.975(dof) * se`` (``interval``).

    ``delay``, ``delay_se`` [s], ``delay_dof``: the fitted force-channel delay
    (``acquisition="delay"``; 0, 0 and NaN otherwise). ``lack_of_fit`` ``(2, 2)`` and
    ``lack_of_fit_overall``: the residuals' weighted sum of squares over its expected value
    when the model holds (about 1 then; larger when it does not), and ``lack_of_fit_p``,
    ``lack_of_fit_p_overall``: their p-values (an F test); NaN without ``Estimate.error``.
    Under ``jax.vmap`` every field gains the batch axis.
    """

    mass: jnp.ndarray
    damping: jnp.ndarray
    stiffness: jnp.ndarray
    mass_se: jnp.ndarray
    damping_se: jnp.ndarray
    stiffness_se: jnp.ndarray
    vaf: jnp.ndarray
    vaf_overall: jnp.ndarray
    dof: jnp.ndarray
    delay: jnp.ndarray
    delay_se: jnp.ndarray
    delay_dof: jnp.ndarray
    lack_of_fit: jnp.ndarray
    lack_of_fit_p: jnp.ndarray
    lack_of_fit_overall: jnp.ndarray
    lack_of_fit_p_overall: jnp.ndarray

    def impedance(self, f, *, acquisition: str = "plain", period: float = CONTROL_PERIOD):
        """The fitted model at ``f`` [Hz] ``(F,)``: ``(F, 2, 2)`` [N/m]. ``acquisition="plain"``
        (default): the arm's ``M s^2 + B s + K`` at ``s = j 2 pi f``; another acquisition gives
        the model of the recorded ``Z`` (``fit_impedance``), with ``period`` ``L`` [s]."""
        check_choice("acquisition", acquisition, ACQUISITIONS)
        omega = 2.0 * jnp.pi * jnp.asarray(f, dtype=jnp.float64)
        x = _regressors(omega, acquisition, period)  # (F, 3): K, M, B
        z = sum(x[:, k, None, None] * p[None] for k, p in enumerate((self.stiffness, self.mass, self.damping)))
        if acquisition == "delay":
            z = z * jnp.exp(-1j * omega * self.delay)[:, None, None]
        return z

    def interval(self, name: str, level: float = 0.95):
        """Two-sided ``level`` interval of ``name`` (``"mass"``, ``"damping"``, ``"stiffness"``
        or ``"delay"``) as ``(low, high)`` NumPy arrays: ``value -+ t_(1+level)/2(dof) * se``
        (host only: the quantile comes from SciPy)."""
        import scipy.stats

        check_choice("parameter", name, ("mass", "damping", "stiffness", "delay"))
        value, se = np.asarray(getattr(self, name)), np.asarray(getattr(self, f"{name}_se"))
        dof = np.asarray(self.delay_dof if name == "delay" else self.dof)
        half = scipy.stats.t.ppf(0.5 + level / 2, np.where(np.isfinite(dof), dof, np.inf)) * se
        return value - half, value + half

    def warnings(self, est: Estimate | None = None) -> list[str]:
        """``fit_warnings(self, est)``: what makes this fit untrustworthy, in words."""
        from .diagnose import fit_warnings

        return fit_warnings(self, est)


def coherence_weights(est: Estimate):
    """Coherence weights ``(F, 2, 2)`` for ``Z = T R^-1`` from an ``Estimate``.

    An H1 row estimated with multiple coherence ``g`` has relative variance proportional to
    ``e = (1 - g) / g`` (the inverse of the first specification's ``g / (1 - g)`` weighting). ``Z_ij``
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


def _regressors(omega, acquisition: str, period):
    """Complex regressors ``(F, 3)`` of ``K, M, B`` in the recorded ``Z`` (the delay apart)."""
    if acquisition == "instant":
        # s (1 - exp(-s L)) / L with s = j w, written without the cancellation of 1 - exp(-j w L)
        half = 0.5 * omega * period
        c_m = -2.0 * omega * jnp.sin(half) / period * jnp.exp(-1j * half)
    else:
        c_m = -(omega**2) + 0j
    return jnp.stack([jnp.ones_like(omega) + 0j, c_m, 1j * omega], axis=-1)


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


def _no_extras() -> dict:
    """The fields beyond today's: no delay, no lack-of-fit test."""
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


def _legacy_fit(z, f, w) -> ImpedanceFit:
    """Today's fit (``acquisition="plain"``, ``se="residual"``), unchanged to the bit."""
    omega = 2.0 * jnp.pi * f
    # Regressors scaled to [0, 1]: w^4 reaches ~1e13 at 500 Hz, which round-off would feel.
    w0 = jnp.max(omega)
    u = ((omega / w0) ** 2)[:, None, None]  # (F, 1, 1)
    v = (omega / w0)[:, None, None]
    re, im = jnp.real(z), jnp.imag(z)

    s0 = jnp.sum(w, axis=0)
    u_bar = jnp.sum(w * u, axis=0) / s0
    du = u - u_bar[None]  # weight-centred: the (K, M) normal matrix becomes diagonal
    s_uu = jnp.sum(w * du**2, axis=0)
    s_vv = jnp.sum(w * v**2, axis=0)
    a = jnp.sum(w * re, axis=0) / s0  # intercept at u_bar
    c = jnp.sum(w * du * re, axis=0) / s_uu  # slope in u, = -w0^2 M
    b = jnp.sum(w * v * im, axis=0) / s_vv  # = w0 B

    r_re = re - (a[None] + c[None] * du)
    r_im = im - b[None] * v
    dof = 2.0 * jnp.sum(w > 0, axis=0) - 3.0
    s2 = jnp.sum(w * (r_re**2 + r_im**2), axis=0) / dof
    var_a, var_c, var_b = s2 / s0, s2 / s_uu, s2 / s_vv

    fit = ImpedanceFit(
        mass=-c / w0**2,
        damping=b / w0,
        stiffness=a - c * u_bar,
        mass_se=jnp.sqrt(var_c) / w0**2,
        damping_se=jnp.sqrt(var_b) / w0,
        stiffness_se=jnp.sqrt(var_a + u_bar**2 * var_c),  # K = a - c u_bar, a and c uncorrelated
        vaf=jnp.zeros((2, 2)),
        vaf_overall=jnp.zeros(()),
        dof=dof,
        **_no_extras(),
    )
    err = jnp.abs(z - fit.impedance(f)) ** 2
    power = jnp.abs(z) ** 2
    return fit._replace(
        vaf=100.0 * (1.0 - jnp.sum(err, axis=0) / jnp.sum(power, axis=0)),
        vaf_overall=100.0 * (1.0 - jnp.sum(err) / jnp.sum(power)),
    )


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
    acquisition: str = "plain",
    period: float = CONTROL_PERIOD,
    se: str = "residual",
    error: ZError | None = None,
) -> ImpedanceFit:
    """Fit ``M, B, K`` to an impedance ``Z(f)`` element by element (docs/model.md section 13).

    Args:
        Z: impedance [N/m] ``(F, 2, 2)`` complex, indexed ``[output, input]`` (e.g.
            ``Estimate.Z``); or an ``Estimate``, whose ``Z``, ``f`` and ``error`` are used
            (then ``f`` and ``error`` must be omitted).
        f: frequencies [Hz] ``(F,)``, ``>= 0`` with at least two distinct values.
        weights: ``None`` (uniform), an array ``(F,)`` or ``(F, 2, 2)`` of weights ``>= 0``
            (per bin, or per bin and element), or, with an ``Estimate``, ``"uniform"`` or
            ``"coherence"`` (``coherence_weights``).
        acquisition: how the record was sampled, which decides the model of the recorded
            ``Z``: ``"plain"`` (default: ``M s^2 + B s + K`` as it stands), ``"instant"``
            (samples at the control instants, force just before the hold's update:
            ``M s (1 - exp(-s L)) / L + B s + K``), ``"interval_mean"`` (box-car means:
            ``M s^2 + B s + K``), or ``"delay"`` (``exp(-s tau) (M s^2 + B s + K)`` with the
            force-channel delay ``tau`` fitted too). docs/estimation.md section 2.
        period: the hold (control and acquisition) period ``L`` [s] of ``"instant"``
            (default 1 ms, the simulator's).
        se: ``"residual"`` (default): the usual WLS errors from the residuals, one pooled
            variance per element and independent bins (too small for Welch estimates,
            whose bins are correlated); ``"spectral"``: from the estimate's error model
            ``error`` (``estimate(..., errors=True)``), a sandwich covariance over
            correlated bins of unequal variance. docs/estimation.md section 3.
        error: a ``ZError`` for a ``Z`` array (with an ``Estimate``, its own ``error``).

    The lack-of-fit fields need ``error`` (else NaN), whatever ``se``. Solved in closed form
    (``"delay"``: Gauss-Newton on ``tau`` with ``M, B, K`` eliminated, from ``tau = 0``, a
    fixed number of steps), on regressors scaled by the highest frequency.

    Returns an ``ImpedanceFit``. Single fit; ``jax.vmap`` batches it (shape checks are
    static; value checks, e.g. NaN in ``Z``, run only on concrete inputs). Differentiable
    in ``Z``, ``f``, ``weights`` and ``error``; standard errors have no finite gradient on
    noise-free data (``sqrt`` at 0).
    """
    require_x64("fit_impedance")
    check_choice("acquisition", acquisition, ACQUISITIONS)
    check_choice("se", se, SE_METHODS)
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
    elif isinstance(weights, str):
        raise ValueError(f"weights={weights!r} needs an Estimate as the first argument; with a Z array pass an array")
    if f is None:
        raise ValueError("f (the frequencies of Z [Hz], shape (F,)) is required with a Z array")
    if se == "spectral" and error is None:
        raise ValueError(
            'se="spectral" needs the estimate\'s error model: fit an Estimate from estimate(..., errors=True) '
            "(or pass error=Estimate.error)"
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
    if acquisition == "instant":
        try:
            period = float(period)
        except (TypeError, ValueError):
            raise ValueError(f"period must be a number (the hold period [s]), got {period!r}") from None
        if not 0 < period < math.inf:
            raise ValueError(f"period must be a finite hold period > 0 s, got {period!r}")
    w = _as_weights(weights, n_freq, f)
    if error is not None:
        error = _as_error(error, n_freq)

    if acquisition == "plain" and se == "residual":
        fit = _legacy_fit(z, f, w)
        if error is None:
            return fit
        return _general_fit(z, f, w, acquisition, period, se, error)._replace(
            **{k: getattr(fit, k) for k in ImpedanceFit._fields if not k.startswith("lack_of_fit")}
        )
    return _general_fit(z, f, w, acquisition, period, se, error)


def _general_fit(z, f, w, acquisition, period, se, error) -> ImpedanceFit:
    n_freq = z.shape[0]
    omega = 2.0 * jnp.pi * f
    w0 = jnp.max(omega)
    scale = jnp.stack([jnp.ones(()), w0**2, w0])  # K, M, B: the fit solves for K, w0^2 M, w0 B
    x = _regressors(omega, acquisition, period) / scale[None]  # (F, 3), entries O(1)
    v = omega / w0
    y = z.reshape(n_freq, 4)  # element e = 2 i + j
    wts = w.reshape(n_freq, 4)
    delay = acquisition == "delay"

    tau = jnp.zeros(())  # w0 * delay
    if delay:
        for _ in range(DELAY_ITERATIONS):
            rot = jnp.exp(1j * v * tau)[:, None]
            theta, a = _solve_elements(x, wts, y * rot)
            r = y * rot - x @ theta.T
            dy = 1j * v[:, None] * y * rot  # d(y rot)/d tau
            c = jnp.linalg.solve(a, jnp.real(jnp.einsum("fe,fp,fe->ep", wts, jnp.conj(x), dy))[..., None])[..., 0]
            dyp = dy - x @ c.T  # its part that M, B, K cannot absorb
            tau = tau - jnp.sum(wts * jnp.real(jnp.conj(dyp) * r)) / jnp.sum(wts * jnp.abs(dyp) ** 2)
    phase = jnp.exp(-1j * v * tau)[:, None]  # (F, 1)
    theta, _ = _solve_elements(x, wts, y * jnp.conj(phase))
    model = (x @ theta.T) * phase  # (F, 4): the recorded Z as fitted
    r = y - model

    # Jacobian of the recorded model in the parameters [theta_e (3 each) ..., tau]: (F, 4, P)
    n_par = 13 if delay else 12
    eye4 = jnp.eye(4)
    jac = (eye4[None, :, :, None] * (x * phase)[:, None, None, :]).reshape(n_freq, 4, 12)
    if delay:
        jac = jnp.concatenate([jac, (-1j * v[:, None] * model)[..., None]], axis=-1)
    normal = jnp.real(jnp.einsum("fe,fep,feq->pq", wts, jnp.conj(jac), jac))
    g = jnp.linalg.solve(normal, jnp.swapaxes(jnp.conj(jac) * wts[..., None], 0, 2).reshape(n_par, 4 * n_freq))
    g = jnp.swapaxes(g.reshape(n_par, 4, n_freq), 0, 2).reshape(n_freq, 4, n_par)
    gk = jnp.swapaxes(g, -1, -2)  # (F, P, 4): the parameters' error is Re sum_k gk[k] dZ[k]

    if error is not None:
        root = jnp.einsum("fac,fbd->fabcd", _sqrt_psd2(error.force), _sqrt_psd2(error.position)).reshape(n_freq, 4, 4)
        rho = jnp.asarray(error.bin_corr)
        q = gk @ root  # (F, P, 4)
        yq = _banded_sum(q, q, rho, lambda a, b: b)  # sum_d rho q[k + d]
        cov_spec = 0.5 * jnp.real(jnp.einsum("fpm,fqm->pq", yq, jnp.conj(q)))
        cov_spec = 0.5 * (cov_spec + cov_spec.T)
    if se == "residual":
        dof_e = 2.0 * jnp.sum(wts > 0, axis=0) - 3.0
        s2 = jnp.sum(wts * jnp.abs(r) ** 2, axis=0) / dof_e  # (4,)
        meat = jnp.real(jnp.einsum("fe,fep,feq->pq", wts * s2[None], jnp.conj(jac), jac))
        cov = jnp.linalg.solve(normal, jnp.linalg.solve(normal, meat).T)
        dof = dof_e.reshape(2, 2)
        par_dof = jnp.concatenate([jnp.repeat(dof_e, 3), jnp.full((n_par - 12,), jnp.min(dof_e))])
    else:
        cov = cov_spec
        # Satterthwaite: the variance is a sum of bins' residual spectra, each with error.dof
        # degrees of freedom and correlated between bins as bin_corr^2.
        share = jnp.abs(0.5 * jnp.real(jnp.einsum("fpm,fpm->fp", yq, jnp.conj(q))))  # (F, P)
        rel = share / jnp.sqrt(error.dof)[:, None]  # each share's sd is sqrt(2 / dof) of it
        spread = _banded_sum(rel, rel, rho**2, lambda a, b: a * b)
        par_dof = jnp.sum(share, axis=0) ** 2 / jnp.sum(spread, axis=0)
        dof = jnp.min(par_dof[:12].reshape(4, 3), axis=-1).reshape(2, 2)

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
        vaf=100.0 * (1.0 - jnp.sum(jnp.abs(r) ** 2, axis=0) / jnp.sum(jnp.abs(y) ** 2, axis=0)).reshape(2, 2),
        vaf_overall=100.0 * (1.0 - jnp.sum(jnp.abs(r) ** 2) / jnp.sum(jnp.abs(y) ** 2)),
        dof=dof,
        **_no_extras(),
    )
    if delay:
        fit = fit._replace(delay=tau / w0, delay_se=sd[12] / w0, delay_dof=par_dof[12])
    if error is None:
        return fit
    return fit._replace(**_lack_of_fit(r, wts, jac, root, gk, yq, cov_spec, rho, error.dof))


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
