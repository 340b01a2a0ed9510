"""Random force perturbations F_Delta (docs/model.md section 10): filtered uniform noise from a PRNG key.

Per axis: i.i.d. uniform samples on [-1, 1] at 1 kHz, an 8th-order Butterworth low-pass
(15 Hz, second-order sections from ``scipy.signal.butter``) applied causally, the first
2 s of filter output discarded, then scaled so that ``max_k |F_Delta,k|`` equals the peak.
Single-trial; batch over keys with ``jax.vmap``.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import scipy.signal

from .._checks import as_float64, check_int, check_key, is_concrete, require_x64
from .timing import SAMPLE_RATE

PERTURBATION_CUTOFF = 15.0  # Butterworth cut-off f_max [Hz]
PERTURBATION_ORDER = 8
PERTURBATION_WARMUP = 2000  # samples of filter output discarded (2 s at 1 kHz)


@functools.cache
def butterworth_sos(order: int = PERTURBATION_ORDER, cutoff: float = PERTURBATION_CUTOFF, fs: float = SAMPLE_RATE):
    """Low-pass Butterworth as second-order sections, ``(order/2, 6)`` NumPy float64."""
    return scipy.signal.butter(order, cutoff, btype="low", fs=fs, output="sos")


def sosfilt(sos, x):
    """Causal filtering of ``x`` ``(N, C)`` along axis 0, zero initial state.

    Transposed direct form II per section, the same recursion as ``scipy.signal.sosfilt``
    (agreement to round-off). ``sos`` is ``(S, 6)`` with rows ``[b0, b1, b2, 1, a1, a2]``.
    """
    sos = jnp.asarray(sos, dtype=x.dtype)
    zi0 = jnp.zeros((sos.shape[0], 2) + x.shape[1:], dtype=x.dtype)
    return jax.lax.scan(lambda zi, xn: sos_step(sos, zi, xn), zi0, x)[1]


def sos_step(sos, zi, xn):
    """One sample of ``sosfilt``: the new state ``(S, 2, C)`` and the output ``(C,)`` for the
    input ``xn`` ``(C,)`` and state ``zi`` (what a sample-by-sample loop such as the
    voluntary force of ``_model/voluntary.py`` runs)."""
    new = []
    for i in range(sos.shape[0]):
        b0, b1, b2, _, a1, a2 = (sos[i, j] for j in range(6))
        yn = b0 * xn + zi[i, 0]
        new.append(jnp.stack([b1 * xn - a1 * yn + zi[i, 1], b2 * xn - a2 * yn]))
        xn = yn
    return jnp.stack(new), xn


def perturbation(
    key,
    n_samples: int,
    peak,
    *,
    warmup: int = PERTURBATION_WARMUP,
    cutoff: float = PERTURBATION_CUTOFF,
    order: int = PERTURBATION_ORDER,
):
    """A perturbation record ``F_Delta`` [N], shape ``(n_samples, 2)`` float64, at 1 kHz.

    Args:
        key: a ``jax.random`` key; the same key always gives the same signal.
        n_samples: record length (integer >= 1), one sample per 1 ms control period.
        peak: per-axis peak [N], a scalar or ``(2,)`` (e.g. ``paper.perturbation_peak(1)``).
        warmup: filter start-up samples drawn and discarded (default 2000 = 2 s).
        cutoff: Butterworth cut-off [Hz] (default 15), below Nyquist (500 Hz).
        order: Butterworth order (even integer >= 2, default 8).

    The paper's per-level peaks are ``paper.perturbation_peak(level)``.
    """
    require_x64("perturbation")
    check_key(key, where="perturbation")
    n_samples = check_int("n_samples", n_samples, minimum=1)
    warmup = check_int("warmup", warmup, minimum=0)
    peak = as_float64("peak", peak, where="perturbation")
    if peak.shape not in ((), (2,)):
        raise ValueError(f"peak must be a scalar or have shape (2,), got {peak.shape}")
    if is_concrete(peak) and not np.all(np.asarray(peak) > 0):
        raise ValueError(f"peak must be > 0 N, got {np.asarray(peak).tolist()}")
    if not 0.0 < cutoff < SAMPLE_RATE / 2:
        raise ValueError(f"cutoff must be in (0, {SAMPLE_RATE / 2:g}) Hz, got {cutoff}")
    order = check_int("order", order, minimum=2)
    if order % 2:
        raise ValueError(f"order must be even (second-order sections), got {order}")
    sos = jnp.asarray(butterworth_sos(order=order, cutoff=float(cutoff)), dtype=jnp.float64)
    return _scaled_filtered_noise(key, sos, peak, n_samples=n_samples, warmup=warmup)


@functools.partial(jax.jit, static_argnames=("n_samples", "warmup"))
def _scaled_filtered_noise(key, sos, peak, *, n_samples: int, warmup: int):
    """``perturbation``'s signal as one compiled program per record length (op by op, each
    operation and the filter's scan would compile on its own)."""
    noise = jax.random.uniform(key, (warmup + n_samples, 2), dtype=jnp.float64, minval=-1.0, maxval=1.0)
    filtered = sosfilt(sos, noise)[warmup:]
    scale = jnp.broadcast_to(peak, (2,)) / jnp.max(jnp.abs(filtered), axis=0)
    return filtered * scale[None, :]
