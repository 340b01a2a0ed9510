"""The impedance estimate of a record (docs/model.md section 11, paper eq. 9): ``Estimate``,
``estimate`` and ``input_coherence`` on the Welch machinery of ``welch.py``, and the hand
force's broadband excess (``force_excess``) that stick-slip leaves in a record.

Single-trial functions; batch with ``jax.vmap``. Differentiable end to end.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .._checks import as_float64, require_x64
from .._model.timing import SAMPLE_RATE
from .welch import (
    ESTIMATION_FMAX,
    ZError,
    _inv2,
    _segments,
    band_spectra,
    check_finite,
    check_welch,
    coherences,
    cross_spectral_matrix,
    h1,
    ordinary_coherence,
    welch_window,
    z_error,
)


class Estimate(NamedTuple):
    """Estimator output on the bins ``0 < f <= fmax``.

    ``f`` ``(F,)`` [Hz]; ``R`` (F_Delta -> x) [m/N], ``T`` (F_Delta -> F_h) [N/N] and
    ``Z = T R^-1`` [N/m], each ``(F, 2, 2)`` complex indexed ``[output, input]``;
    ``coh_multiple_x`` ``(F, 2)`` per output; ``coh_partial_x`` ``(F, 2, 2)``
    ``[output, input]``; the same two for ``fh``; ``coh_inputs`` ``(F,)`` the ordinary
    coherence between the two perturbation axes; ``error``: the ``ZError`` of ``Z`` (``None``
    from ``estimate(..., errors=False)``); ``force_excess`` ``(2,)`` per force axis: the
    hand force's broadband power the perturbation does not explain, over its power in the band
    (``force_excess``; ``None`` for an ``Estimate`` built by hand).
    """

    f: jnp.ndarray
    R: jnp.ndarray
    T: jnp.ndarray
    Z: jnp.ndarray
    coh_multiple_x: jnp.ndarray
    coh_partial_x: jnp.ndarray
    coh_multiple_fh: jnp.ndarray
    coh_partial_fh: jnp.ndarray
    coh_inputs: jnp.ndarray
    error: ZError | None = None
    force_excess: jnp.ndarray | None = None


EXCESS_BAND = (2.0, 0.4)  # the broadband excess: from 2 fmax to 0.4 fs (below the anti-alias roll-off)


def force_excess(f_delta, fh, *, fs: float, nperseg: int, noverlap: int, fmax: float, window="hann", nfft=None):
    """Per force axis ``(2,)``: the hand force's power from ``2 fmax`` to ``0.4 fs`` that the
    perturbation does not explain linearly (``(1 - multiple coherence) G_ff``), over the
    force's power in the band ``0 < f <= fmax``; NaN where that range holds no bin.

    A linear loop driven in the band answers in the band: above it the force holds the sensor's
    noise, when the perturbation is band-limited (the paper's, and the designed families; a
    broadband one whose force rises far above the band leaves its estimate's leakage there).
    Stick-slip in the robot's joints jerks the hand and spreads force over every frequency
    (measured values in docs/estimation.md section 3)."""
    nfft = nperseg if nfft is None else nfft
    freqs = np.arange(nfft // 2 + 1) * (fs / nfft)
    band = np.flatnonzero((freqs > 0) & (freqs <= fmax))
    high = np.flatnonzero((freqs >= EXCESS_BAND[0] * fmax) & (freqs <= EXCESS_BAND[1] * fs))
    if high.size == 0:
        return jnp.full((2,), jnp.nan)
    _, g = cross_spectral_matrix(
        jnp.concatenate([f_delta, fh], axis=1),
        fs=fs,
        nperseg=nperseg,
        noverlap=noverlap,
        nbins=int(high[-1]) + 1,
        window=window,
        nfft=nfft,
    )
    out = []
    for c in (2, 3):
        coh = coherences(g[high], (0, 1), c)[0]
        coh = jnp.where(jnp.isfinite(coh), jnp.clip(coh, 0.0, 1.0), 0.0)  # no input power there: none explained
        out.append(jnp.sum(jnp.real(g[high, c, c]) * (1.0 - coh)) / jnp.sum(jnp.real(g[band, c, c])))
    return jnp.stack(out)


def estimate(
    f_delta,
    x,
    fh,
    *,
    fs: float = SAMPLE_RATE,
    nperseg: int | None = None,
    noverlap: int | None = None,
    fmax: float = ESTIMATION_FMAX,
    window="hann",
    nfft: int | None = None,
    errors: bool = True,
) -> Estimate:
    """Estimate the arm impedance from a record (docs/model.md section 11, paper eq. 9).

    Args:
        f_delta: perturbation ``(N, 2)`` [N] (the inputs).
        x: recorded hand position ``(N, 2)`` [m] (any constant offset is removed per segment).
        fh: recorded hand force ``(N, 2)`` [N].
        fs: sample rate [Hz].
        nperseg, noverlap: Welch segment length and overlap [samples]; by default they follow
            the record (``welch_segments``: Table 4's 8192 and 6144 from 24576 samples on,
            shorter segments on a shorter record); a given ``nperseg`` alone gets 75% overlap.
        fmax: highest frequency of interest [Hz], between ``fs / nfft`` and Nyquist.
        window: ``"hann"`` (periodic, default), any name or tuple ``scipy.signal.get_window``
            knows (periodic), or an array ``(nperseg,)``.
        nfft: FFT length ``>= nperseg`` (zero padding; default ``nperseg``); bins are
            ``fs / nfft`` apart.
        errors: also return ``Estimate.error``, the ``ZError`` of ``Z`` (what
            ``fit_impedance``'s spectral standard errors and its lack-of-fit test need). On by
            default; ``False`` saves its memory (about 0.1 MB a trial) where only ``Z`` and the
            coherences are wanted. The other fields are the same either way.

    Single-trial; ``jax.vmap`` batches it (the settings are static). Raises ``ValueError``
    for mismatched lengths, NaN or inf in a concrete record (naming the first bad sample),
    a record that gives fewer than two segments, ``noverlap >= nperseg``, ``nfft <
    nperseg``, an unknown window or ``fmax`` out of range.
    """
    require_x64("estimate")
    arrays = [as_float64(name, a, where="estimate") for name, a in (("f_delta", f_delta), ("x", x), ("fh", fh))]
    shapes = [a.shape for a in arrays]
    if any(len(s) != 2 or s[1] != 2 for s in shapes) or len(set(shapes)) != 1:
        raise ValueError(f"f_delta, x and fh must all have the same shape (N, 2); got {shapes}")
    for name, a in zip(("f_delta", "x", "fh"), arrays, strict=True):
        check_finite(name, a, where="estimate")
    nperseg, noverlap = _segments(shapes[0][0], nperseg, noverlap)
    settings = dict(fs=fs, nperseg=nperseg, noverlap=noverlap, fmax=fmax, window=window, nfft=nfft, errors=errors)
    if isinstance(window, (str, tuple)):
        # one compiled program per record shape and settings, not a few hundred op-by-op ones
        return _estimate_compiled(*arrays, **settings)
    # an array window: checked here on its values (under jit they could not be), then an argument
    check_welch(shapes[0][0], fs=fs, nperseg=nperseg, noverlap=noverlap, nfft=nfft, window=window)
    settings["window"] = welch_window(window, nperseg)
    return _estimate_compiled_window(*arrays, **settings)


def _estimate_numbers(f_delta, x, fh, *, fs, nperseg, noverlap, fmax, window, nfft, errors) -> Estimate:
    """``estimate``'s numbers from checked records and settings."""
    freqs, g = band_spectra(
        jnp.concatenate([f_delta, x, fh], axis=1),
        fs=fs,
        nperseg=nperseg,
        noverlap=noverlap,
        fmax=fmax,
        window=window,
        nfft=nfft,
    )
    n_seg = check_welch(f_delta.shape[0], fs=fs, nperseg=nperseg, noverlap=noverlap, nfft=nfft, window=window)
    u, xs, fs_ = (0, 1), (2, 3), (4, 5)
    r, t = h1(g, u, xs), h1(g, u, fs_)
    z = t @ _inv2(r)
    cx = [coherences(g, u, c) for c in xs]
    cf = [coherences(g, u, c) for c in fs_]
    return Estimate(
        f=freqs,
        R=r,
        T=t,
        Z=z,
        coh_multiple_x=jnp.stack([m for m, _ in cx], -1),
        coh_partial_x=jnp.stack([p for _, p in cx], 1),
        coh_multiple_fh=jnp.stack([m for m, _ in cf], -1),
        coh_partial_fh=jnp.stack([p for _, p in cf], 1),
        coh_inputs=ordinary_coherence(g, 0, 1),
        error=z_error(g, z, n_seg, nperseg=nperseg, noverlap=noverlap, window=window, nfft=nfft) if errors else None,
        force_excess=force_excess(
            f_delta, fh, fs=fs, nperseg=nperseg, noverlap=noverlap, fmax=fmax, window=window, nfft=nfft
        ),
    )


_estimate_compiled = jax.jit(
    _estimate_numbers, static_argnames=("fs", "nperseg", "noverlap", "fmax", "window", "nfft", "errors")
)
_estimate_compiled_window = jax.jit(
    _estimate_numbers, static_argnames=("fs", "nperseg", "noverlap", "fmax", "nfft", "errors")
)


def input_coherence(
    f_delta,
    *,
    fs: float = SAMPLE_RATE,
    nperseg: int | None = None,
    noverlap: int | None = None,
    fmax: float = ESTIMATION_FMAX,
    window="hann",
    nfft: int | None = None,
):
    """Maximum ordinary coherence between the two perturbation axes over ``0 < f <= fmax``.

    The paper kept it below 0.4; report it with every trial. Scalar; vmappable. Welch
    settings as in ``estimate``.
    """
    require_x64("input_coherence")
    f_delta = as_float64("f_delta", f_delta, where="input_coherence")
    if f_delta.ndim != 2 or f_delta.shape[1] != 2:
        raise ValueError(f"f_delta must have shape (N, 2), got {f_delta.shape}")
    check_finite("f_delta", f_delta, where="input_coherence")
    nperseg, noverlap = _segments(f_delta.shape[0], nperseg, noverlap)
    _, g = band_spectra(f_delta, fs=fs, nperseg=nperseg, noverlap=noverlap, fmax=fmax, window=window, nfft=nfft)
    return jnp.max(ordinary_coherence(g, 0, 1))
