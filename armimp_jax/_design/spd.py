"""Unconstrained parameters <-> symmetric positive definite matrices.

Tuning (IMBIC's ``Mhat``), identification and experiment design all search over matrices
that must stay symmetric positive definite; an optimiser works best on unconstrained
numbers. ``"diagonal"``: the logs of the diagonal (``n`` numbers); ``"full"``: a
Cholesky factor with a log-diagonal, row by row (``n (n + 1) / 2`` numbers). The map is
smooth and one-to-one, so gradients and Gauss-Newton steps pass through it.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from .._checks import check_choice

STRUCTURES = ("diagonal", "full")


def n_theta(n: int, structure: str) -> int:
    """Length of ``theta`` for an ``(n, n)`` matrix: ``n`` (diagonal) or ``n (n + 1) / 2`` (full)."""
    check_choice("structure", structure, STRUCTURES)
    return n if structure == "diagonal" else n * (n + 1) // 2


def _size(length: int, structure: str) -> int:
    if structure == "diagonal":
        return length
    n = int(round((np.sqrt(8 * length + 1) - 1) / 2))
    if n * (n + 1) // 2 != length:
        raise ValueError(f"a full SPD parameter vector has n (n + 1) / 2 entries, got {length}")
    return n


def spd_from_theta(theta, structure: str):
    """The SPD matrix ``(n, n)`` of the unconstrained ``theta`` (see the module docstring).

    Differentiable and traceable; ``jax.vmap`` maps it over a leading axis of ``theta``.
    """
    check_choice("structure", structure, STRUCTURES)
    theta = jnp.asarray(theta)
    n = _size(theta.shape[-1], structure)
    if structure == "diagonal":
        return jnp.diag(jnp.exp(theta))
    rows, cols = np.tril_indices(n)
    values = jnp.where(jnp.asarray(rows == cols), jnp.exp(theta), theta)
    lower = jnp.zeros((n, n), theta.dtype).at[rows, cols].set(values)
    return lower @ lower.T


def theta_from_spd(matrix, structure: str, *, name: str = "matrix"):
    """Inverse of ``spd_from_theta`` for a concrete SPD ``matrix`` (``"diagonal"`` keeps
    only its diagonal); a one-line ``ValueError`` naming ``name`` when it is not SPD."""
    check_choice("structure", structure, STRUCTURES)
    matrix = np.asarray(matrix, dtype=float)
    if structure == "diagonal":
        if np.any(np.diag(matrix) <= 0):
            raise ValueError(f"{name} diagonal must be positive, got {np.diag(matrix).tolist()}")
        return jnp.log(jnp.asarray(np.diag(matrix)))
    try:
        lower = np.linalg.cholesky(matrix)
    except np.linalg.LinAlgError:
        raise ValueError(f"{name} must be symmetric positive definite, got {matrix.tolist()}") from None
    rows, cols = np.tril_indices(matrix.shape[0])
    values = lower[rows, cols]
    return jnp.asarray(np.where(rows == cols, np.log(np.where(rows == cols, values, 1.0)), values))
