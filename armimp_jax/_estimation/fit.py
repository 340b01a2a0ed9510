"""Parametric identification (spec section 11b): the arm's M, B, K with standard errors and VAF.

Each element of a measured impedance is linear in three parameters,
``Z_ij(f) ~= K_ij - w^2 M_ij + j w B_ij`` with ``w = 2 pi f`` (``Z`` force per displacement
[N/m], ``Z = M s^2 + B s + K`` at ``s = j w``, as ``Arm.impedance``). The real part gives
``K`` and ``M``, the imaginary part ``B``, by closed-form weighted least squares over the
bins; the two parts share one residual variance (``2F - 3`` degrees of freedom).

Single-fit functions; batch with ``jax.vmap``. Closed form, so differentiable end to end.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from .._checks import as_float64, is_concrete, require_x64
from .welch import Estimate


class ImpedanceFit(NamedTuple):
    """``M, B, K`` fitted to an impedance, with standard errors and %VAF (a pytree).

    ``mass`` [kg], ``damping`` [N s/m], ``stiffness`` [N/m], each ``(2, 2)`` indexed
    ``[output, input]`` like ``Z``, and their standard errors ``mass_se``, ``damping_se``,
    ``stiffness_se`` (same units and shapes). ``vaf`` ``(2, 2)`` and ``vaf_overall`` (scalar):
    variance accounted for [%], ``100 (1 - sum |Z - Z_fit|^2 / sum |Z|^2)`` per element and
    over all elements. ``dof`` ``(2, 2)``: residual degrees of freedom ``2 F_w - 3`` (``F_w``:
    bins with positive weight); a two-sided 95% interval is ``value +- t_0.975(dof) * se``.
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

    def impedance(self, f):
        """The fitted model ``M s^2 + B s + K`` at ``s = j 2 pi f``, ``f`` [Hz] ``(F,)``: ``(F, 2, 2)`` [N/m]."""
        s = 2j * jnp.pi * jnp.asarray(f, dtype=jnp.float64)[:, None, None]
        return self.mass[None] * s**2 + self.damping[None] * s + self.stiffness[None]


def coherence_weights(est: Estimate):
    """Coherence weights ``(F, 2, 2)`` for ``Z = T R^-1`` from an ``Estimate``.

    An H1 row estimated with multiple coherence ``g`` has relative variance proportional to
    ``e = (1 - g) / g`` (the inverse of the spec's ``g / (1 - g)`` weighting). ``Z_ij``
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


def fit_impedance(Z, f=None, *, weights=None) -> ImpedanceFit:
    """Fit ``Z(f) ~= M s^2 + B s + K`` (``s = j 2 pi f``) element by element (spec section 11b).

    Args:
        Z: impedance [N/m] ``(F, 2, 2)`` complex, indexed ``[output, input]`` (e.g.
            ``Estimate.Z``); or an ``Estimate``, whose ``Z`` and ``f`` are used (then ``f``
            must be omitted).
        f: frequencies [Hz] ``(F,)``, ``>= 0`` with at least two distinct values.
        weights: ``None`` (uniform), an array ``(F,)`` or ``(F, 2, 2)`` of weights ``>= 0``
            (per bin, or per bin and element), or, with an ``Estimate``, ``"uniform"`` or
            ``"coherence"`` (``coherence_weights``).

    For each element, with ``u = w^2`` and ``w = 2 pi f``, weighted least squares on
    ``Re Z = K - u M`` and ``Im Z = w B``, each bin's real and imaginary rows with the
    bin's weight. Solved in closed form on weight-centred, scaled regressors (no normal
    equations in ``w^4``). Residual variance ``s^2 = sum w_k (r_re^2 + r_im^2) / (2 F_w - 3)``
    and covariance ``s^2 (X^T W X)^-1``: the usual WLS formula, exact when the weights are
    proportional to the inverse variances of the bins (uniform weights for white noise;
    coherence weights approximately), optimistic or pessimistic otherwise. The VAF is
    unweighted, over all bins.

    Returns an ``ImpedanceFit``. Single fit; ``jax.vmap`` batches it (shape checks are
    static; value checks run only on concrete inputs). Differentiable in ``Z``, ``f`` and
    ``weights``; standard errors have no finite gradient on noise-free data (``sqrt`` at 0).
    """
    require_x64("fit_impedance")
    if isinstance(Z, Estimate):
        if f is not None:
            raise ValueError("pass an Estimate alone, or Z and f; not an Estimate and f")
        est, Z, f = Z, Z.Z, Z.f
        if isinstance(weights, str):
            if weights not in ("uniform", "coherence"):
                raise ValueError(f"unknown weights {weights!r}; allowed: 'uniform', 'coherence'")
            weights = None if weights == "uniform" else coherence_weights(est)
    elif isinstance(weights, str):
        raise ValueError(f"weights={weights!r} needs an Estimate as the first argument; with a Z array pass an array")
    if f is None:
        raise ValueError("f (the frequencies of Z [Hz], shape (F,)) is required with a Z array")
    z = _as_impedance(Z)
    n_freq = z.shape[0]
    f = as_float64("f", f, where="fit_impedance")
    if f.shape != (n_freq,):
        raise ValueError(f"f must have shape (F,) = ({n_freq},) to match Z {z.shape}, got {f.shape}")
    if is_concrete(f):
        fn = np.asarray(f)
        if not np.all(np.isfinite(fn)) or np.any(fn < 0) or len(np.unique(fn)) < 2:
            raise ValueError("f must be finite, >= 0 Hz and hold at least two distinct frequencies")
    w = _as_weights(weights, n_freq, f)

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
    )
    err = jnp.abs(z - fit.impedance(f)) ** 2
    power = jnp.abs(z) ** 2
    return fit._replace(
        vaf=100.0 * (1.0 - jnp.sum(err, axis=0) / jnp.sum(power, axis=0)),
        vaf_overall=100.0 * (1.0 - jnp.sum(err) / jnp.sum(power)),
    )
