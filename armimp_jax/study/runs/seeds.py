"""Common random numbers: the PRNG key of a study's seed, for its perturbation and its sensor noise.

Every study draws trial seed ``s``'s perturbation from ``fold_in(PRNGKey(base_seed), s)``,
so every condition or point sees the same signal shape for the same seed (scaled to its
peak). What differs between studies is an argument: the reproduction redraws a seed
whose inputs are too coherent (``redraw`` > 0 folds the attempt in once more), the
tuner's training and held-out seeds are offset so they never overlap (``seed`` is the
offset one), and a sweep's sensor noise comes from ``sensor_noise_key``.
"""

from __future__ import annotations

import jax
import numpy as np

from ..._model.perturbation import perturbation


def perturbation_key(base_seed: int, seed: int, *, redraw: int = 0) -> jax.Array:
    """``fold_in(PRNGKey(base_seed), seed)``, folded once more with ``redraw`` when it is not 0
    (a raw ``uint32[2]`` key)."""
    key = jax.random.fold_in(jax.random.PRNGKey(base_seed), seed)
    return key if redraw == 0 else jax.random.fold_in(key, redraw)


def sensor_noise_key(base_seed: int, seed: int) -> np.ndarray:
    """The sensor-noise key of a sweep's trial seed: ``fold_in(perturbation_key, 1)``, as the
    key data that ``simulate_batch(keys=...)`` takes (``uint32[2]``)."""
    return np.asarray(jax.random.key_data(jax.random.fold_in(perturbation_key(base_seed, seed), 1)))


def seed_perturbation(base_seed: int, seed: int, n_samples: int, peak, *, redraw: int = 0) -> np.ndarray:
    """The perturbation ``(n_samples, 2)`` [N] of ``seed`` with per-axis ``peak`` [N]
    (``perturbation`` with ``perturbation_key``)."""
    return np.asarray(perturbation(perturbation_key(base_seed, seed, redraw=redraw), n_samples, np.asarray(peak)))
