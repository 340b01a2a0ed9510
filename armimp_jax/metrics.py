"""Accuracy of an impedance estimate against the true arm (spec section 11, paper eqs. 1-2).

``phi_T`` is the bin-mean of the largest singular value of ``Z_h - Z_hat``; ``phi_ij``
the bin-mean of ``|Z_h,ij - Z_hat,ij|``. Both [N/m]; zero means perfect. Single-trial
and differentiable (the 2x2 singular value is in closed form with a guarded square root).
"""

from __future__ import annotations

import jax.numpy as jnp

from .arm import true_impedance


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


def accuracy(Z, f, location):
    """``(phi_T, phi_ij)`` [N/m] of the estimate ``Z`` ``(F, 2, 2)`` on bins ``f`` ``(F,)`` [Hz]
    for arm ``location`` (1-4, int or traced int). ``phi_T`` scalar, ``phi_ij`` ``(2, 2)``."""
    return impedance_error(Z, true_impedance(location, f))


def impedance_error(Z, Z_true):
    """``(phi_T, phi_ij)`` [N/m] of ``Z`` against ``Z_true``, both ``(F, 2, 2)`` complex."""
    err = Z_true - Z
    return jnp.mean(largest_singular_value(err)), jnp.mean(jnp.abs(err), axis=0)
