"""Accuracy of an impedance estimate against the true arm (docs/model.md section 12, paper eqs. 1-2).

``phi_T`` is the bin-mean of the largest singular value of ``Z_h - Z_hat``; ``phi_ij``
the bin-mean of ``|Z_h,ij - Z_hat,ij|``. Both [N/m]; zero means perfect. Single-trial
and differentiable (the 2x2 singular value is in closed form with a guarded square root).
"""

from __future__ import annotations

import jax.numpy as jnp

from .._model.arm import Arm, impedance_response


def largest_singular_value(a):
    """Spectral norm of ``(..., 2, 2)`` complex matrices, closed form.

    ``s_max^2 = (|A|_F^2 + sqrt(|A|_F^4 - 4 |det A|^2)) / 2``; the square root is guarded
    where its argument is zero (equal singular values) so that gradients stay finite.
    """
    fro2 = jnp.sum(jnp.abs(a) ** 2, axis=(-2, -1))
    det = a[..., 0, 0] * a[..., 1, 1] - a[..., 0, 1] * a[..., 1, 0]
    disc = jnp.maximum(fro2**2 - 4.0 * jnp.abs(det) ** 2, 0.0)
    positive = disc > 0.0
    root = jnp.where(positive, jnp.sqrt(jnp.where(positive, disc, 1.0)), 0.0)
    return jnp.sqrt(0.5 * (fro2 + root))


def accuracy(Z, f, arm: Arm):
    """``(phi_T, phi_ij)`` [N/m] of the estimate ``Z`` ``(F, 2, 2)`` complex on bins ``f``
    ``(F,)`` [Hz] against the true impedance of ``arm``. ``phi_T`` scalar, ``phi_ij`` ``(2, 2)``.
    Single-trial and differentiable; batch with ``jax.vmap`` (over arms too)."""
    if not isinstance(arm, Arm):
        raise ValueError(f"accuracy: arm must be an Arm (e.g. paper.arm(1)), got {type(arm).__name__}")
    Z, f = jnp.asarray(Z), jnp.asarray(f)
    if f.ndim != 1 or Z.shape != (f.shape[0], 2, 2):
        raise ValueError(f"accuracy: Z must have shape (F, 2, 2) for F = len(f) bins; got Z {Z.shape}, f {f.shape}")
    return impedance_error(Z, impedance_response(arm, f))


def impedance_error(Z, Z_true):
    """``(phi_T, phi_ij)`` [N/m] of ``Z`` against ``Z_true``, both ``(F, 2, 2)`` complex."""
    err = Z_true - Z
    return jnp.mean(largest_singular_value(err)), jnp.mean(jnp.abs(err), axis=0)
