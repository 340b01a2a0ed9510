"""Stochastic impedance estimation (docs/model.md section 11): Welch spectra, H1, Z, coherences.

All channels of a record go through one ``jnp.fft.rfft`` (of length ``nfft``, zero
padded) per windowed, mean-removed segment; the cross-spectral matrix is the segment
average of ``conj(X_a) X_b`` (the ``scipy.signal.csd(a, b)`` convention, one-sided density
scaling). The window is the periodic Hann by default, or any window ``scipy.signal.get_window``
knows, or an explicit array. Only the bins the caller needs are kept after the FFT, so a
trial costs ``S x C x nperseg`` reals of segments plus ``S x C x F`` complex spectra (about
8 + 0.3 MB for a 50 s record). The estimate also carries ``ZError`` (unless ``errors=False``), the
covariance of ``Z`` that the Welch average implies (docs/estimation.md, section 3).

Single-trial functions; batch with ``jax.vmap``. Differentiable end to end.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np
import scipy.signal

from .._checks import as_float64, check_int, is_concrete
from .._model.timing import SAMPLE_RATE

# Table 4 of the paper (docs/model.md section 11): 21 segments in a 50 s record.
WELCH_NPERSEG = 8192  # = nfft
WELCH_NOVERLAP = 6144
ESTIMATION_FMAX = 15.0  # [Hz]
N_INPUTS = 2  # perturbation axes: the residual spectrum loses about N_INPUTS * kappa averages


def welch_segments(n_samples: int) -> tuple[int, int]:
    """The Welch segment length and overlap that follow a record's length.

    The largest power of two up to Table 4's ``WELCH_NPERSEG`` (8192) that fits three times
    in the record, with 75% overlap: Table 4's settings from 24576 samples on (the paper's
    50 s record is unchanged), and at least nine segments (about five effective averages) on
    a shorter one, where Table 4's segment would leave as few as two (a 12 s record at 1 kHz
    gets 2048-sample segments, 20 of them). Returns ``(nperseg, noverlap)``; raises
    ``ValueError`` below 24 samples.
    """
    n_samples = check_int("n_samples", n_samples, minimum=24)
    nperseg = int(min(WELCH_NPERSEG, 2 ** math.floor(math.log2(n_samples / 3))))
    return nperseg, 3 * nperseg // 4


def _segments(n_samples: int, nperseg: int | None, noverlap: int | None) -> tuple[int, int]:
    """``estimate``'s defaults: the record's own segments, or 75% overlap of a given ``nperseg``."""
    if nperseg is None:
        auto, auto_overlap = welch_segments(n_samples)
        return auto, auto_overlap if noverlap is None else noverlap
    return nperseg, 3 * nperseg // 4 if noverlap is None else noverlap


def check_finite(name: str, a, *, where: str, index: str = "sample") -> None:
    """Refuse a concrete array with NaN or inf in one line naming ``name`` and the first bad
    entry (its index along axis 0 as ``index``, and the rest of its position); tracers pass."""
    if not is_concrete(a):
        return
    arr = np.asarray(a)
    bad = ~np.isfinite(arr)
    if bad.any():
        pos = tuple(int(i) for i in np.unravel_index(int(np.flatnonzero(bad)[0]), arr.shape))
        rest = {1: "", 2: f", column {pos[-1]}"}.get(len(pos), f", element {pos[1:]}")
        raise ValueError(
            f"{where}: {name} holds a non-finite value, {arr[pos]}, at {index} {pos[0]}{rest}; all must be finite"
        )


class Welch(NamedTuple):
    """Welch settings for batched studies (static; Table 4's by default): segment, overlap,
    highest frequency [Hz], sample rate [Hz], window (a name or tuple
    ``scipy.signal.get_window`` knows; hashable) and FFT length (``None``: ``nperseg``)."""

    nperseg: int = WELCH_NPERSEG
    noverlap: int = WELCH_NOVERLAP
    fmax: float = ESTIMATION_FMAX
    fs: float = SAMPLE_RATE
    window: str | tuple = "hann"
    nfft: int | None = None

    def check(self, n_samples: int) -> None:
        check_welch(n_samples, **self._asdict())


def check_welch(
    n_samples: int,
    *,
    fs: float,
    nperseg: int,
    noverlap: int,
    fmax: float | None = None,
    nfft: int | None = None,
    window="hann",
) -> int:
    """Validate Welch settings for a record of ``n_samples``; return the number of segments.

    Refuses a record that gives fewer than two segments: with one, every coherence is
    identically 1 and H1 is meaningless (docs/model.md section 11).
    """
    nperseg = check_int("nperseg", nperseg, minimum=2)
    noverlap = check_int("noverlap", noverlap, minimum=0)
    nfft = nperseg if nfft is None else check_int("nfft", nfft, minimum=nperseg)
    if not 0 < fs < float("inf"):
        raise ValueError(f"fs must be a finite sample rate > 0 Hz, got {fs}")
    if noverlap >= nperseg:
        raise ValueError(f"noverlap must be smaller than nperseg={nperseg}, got {noverlap}")
    if not (isinstance(window, str) and window == "hann"):
        welch_window(window, nperseg)  # refuse an unknown window or a wrong-length array now
    n_min = 2 * nperseg - noverlap  # two segments
    if n_samples < nperseg:
        raise ValueError(
            f"the record has {n_samples} samples, shorter than one Welch segment (nperseg={nperseg}); "
            f"two segments need >= {n_min} samples ({n_min / fs:g} s at {fs:g} Hz): "
            "use a longer record or a smaller nperseg"
        )
    n_seg = (n_samples - noverlap) // (nperseg - noverlap)
    if n_seg < 2:
        raise ValueError(
            f"the record has {n_samples} samples, which give {n_seg} Welch segment (nperseg={nperseg}, "
            f"noverlap={noverlap}); at least 2 are needed (with one, every coherence is 1): "
            f"use >= {n_min} samples ({n_min / fs:g} s at {fs:g} Hz), a smaller nperseg or a larger noverlap"
        )
    if fmax is not None and not fs / nfft <= fmax <= fs / 2:
        raise ValueError(
            f"fmax must lie between one frequency bin ({fs / nfft:g} Hz) and Nyquist ({fs / 2:g} Hz), got {fmax}"
        )
    return n_seg


def hann(n: int):
    """Periodic Hann window of length ``n`` (``scipy.signal.get_window("hann", n)``)."""
    return 0.5 - 0.5 * jnp.cos(2.0 * jnp.pi * jnp.arange(n) / n)


@functools.lru_cache(maxsize=32)
def _scipy_window(window, nperseg: int) -> np.ndarray:
    try:
        w = scipy.signal.get_window(window, nperseg, fftbins=True)
    except (ValueError, TypeError) as err:
        raise ValueError(f"window {window!r} is not one scipy.signal.get_window knows: {err}") from None
    w = np.asarray(w, dtype=np.float64)
    w.setflags(write=False)  # shared by the cache
    return w


def welch_window(window, nperseg: int):
    """The Welch window ``(nperseg,)`` float64 for ``window``.

    ``"hann"`` (default) is the periodic Hann by formula; any other name or ``(name, param,
    ...)`` tuple is ``scipy.signal.get_window(window, nperseg)`` (periodic), built on the
    host; an array is used as given (length ``nperseg``; it may be traced).
    """
    if isinstance(window, str) and window == "hann":
        return hann(nperseg)  # the formula: keeps the default path's numbers unchanged
    if isinstance(window, (str, tuple)):
        return _scipy_window(window, nperseg)
    w = as_float64("window", window, where="the Welch estimator")
    if w.shape != (nperseg,):
        raise ValueError(f"a window array must have shape (nperseg,) = ({nperseg},), got {w.shape}")
    if is_concrete(w) and not (np.all(np.isfinite(np.asarray(w))) and np.any(np.asarray(w) != 0)):
        raise ValueError("a window array must be finite and not all zero")
    return w


def cross_spectral_matrix(
    signals,
    *,
    fs: float = SAMPLE_RATE,
    nperseg: int = WELCH_NPERSEG,
    noverlap: int = WELCH_NOVERLAP,
    nbins: int | None = None,
    window="hann",
    nfft: int | None = None,
):
    """Welch cross-spectral density matrix of all channel pairs.

    Args:
        signals: ``(N, C)`` real record, ``C`` channels sampled at ``fs`` [Hz]; it must
            give at least two segments.
        nbins: keep only bins ``0 .. nbins-1`` (default: all ``nfft // 2 + 1``).
        window: ``"hann"`` (periodic, default), any name or tuple ``scipy.signal.get_window``
            knows (periodic), or an array ``(nperseg,)``.
        nfft: FFT length ``>= nperseg`` (zero padding; default ``nperseg``); bins are
            ``fs / nfft`` apart.

    Returns:
        ``(freqs (F,), G (F, C, C) complex)`` with ``G[f, a, b] = scipy.signal.csd(a, b)``
        (same window and ``nfft``, ``detrend="constant"``, ``scaling="density"``, one-sided).
    """
    n, _ = signals.shape
    n_seg = check_welch(n, fs=fs, nperseg=nperseg, noverlap=noverlap, nfft=nfft, window=window)
    nfft = nperseg if nfft is None else nfft
    nbins = nfft // 2 + 1 if nbins is None else nbins
    step = nperseg - noverlap
    idx = jnp.arange(n_seg)[:, None] * step + jnp.arange(nperseg)[None, :]
    segments = signals[idx]  # (S, nperseg, C)
    window = welch_window(window, nperseg)
    segments = (segments - jnp.mean(segments, axis=1, keepdims=True)) * window[None, :, None]
    pad = {} if nfft == nperseg else {"n": nfft}  # zero padding after the window, as scipy does
    spectra = jnp.fft.rfft(segments, axis=1, **pad)[:, :nbins, :]  # (S, F, C)
    scale = jnp.full((nbins,), 2.0 / (fs * jnp.sum(window**2)))
    scale = scale.at[0].set(0.5 * scale[0])
    if nfft % 2 == 0 and nbins == nfft // 2 + 1:
        scale = scale.at[-1].set(0.5 * scale[-1])
    g = jnp.einsum("sfa,sfb->fab", jnp.conj(spectra), spectra) * (scale / n_seg)[:, None, None]
    return jnp.arange(nbins) * (fs / nfft), g


def _inv2(a):
    """Inverse of ``(..., 2, 2)`` matrices in closed form."""
    det = a[..., 0, 0] * a[..., 1, 1] - a[..., 0, 1] * a[..., 1, 0]
    adj = jnp.stack([jnp.stack([a[..., 1, 1], -a[..., 0, 1]], -1), jnp.stack([-a[..., 1, 0], a[..., 0, 0]], -1)], -2)
    return adj / det[..., None, None]


def h1(g, inputs, outputs):
    """H1 frequency response ``H[f, k, i]`` (output ``k`` to input ``i``): ``H^T = G_uu^-1 G_uy``."""
    guu = g[:, inputs][:, :, inputs]
    guy = g[:, inputs][:, :, outputs]
    return jnp.swapaxes(_inv2(guu) @ guy, -1, -2)


def coherences(g, inputs, output):
    """Multiple coherence ``(F,)`` of channel ``output`` with both inputs, and its partial
    coherences ``(F, 2)`` (input ``j`` with the other input removed), Bendat & Piersol ch. 7."""
    guu = g[:, inputs][:, :, inputs]
    guy = g[:, inputs, output]
    gyy = jnp.real(g[:, output, output])
    mult = jnp.real(jnp.einsum("fi,fij,fj->f", jnp.conj(guy), _inv2(guu), guy)) / gyy
    partial = []
    for j, o in ((inputs[0], inputs[1]), (inputs[1], inputs[0])):  # o: the other input, removed
        goo = jnp.real(g[:, o, o])
        gjj_l = jnp.real(g[:, j, j]) - jnp.real(g[:, j, o] * g[:, o, j]) / goo
        gjy_l = g[:, j, output] - g[:, j, o] * g[:, o, output] / goo
        gyy_l = gyy - jnp.real(g[:, output, o] * g[:, o, output]) / goo
        partial.append(jnp.abs(gjy_l) ** 2 / (gjj_l * gyy_l))
    return mult, jnp.stack(partial, axis=-1)


def band_spectra(
    signals, *, fs: float, nperseg: int, noverlap: int, fmax: float, window="hann", nfft: int | None = None
):
    """Cross-spectral matrix of ``signals`` ``(N, C)`` on the bins ``0 < f <= fmax`` only
    (validated): ``(freqs (F,), G (F, C, C))``. ``window`` and ``nfft`` as in
    ``cross_spectral_matrix``."""
    check_welch(signals.shape[0], fs=fs, nperseg=nperseg, noverlap=noverlap, fmax=fmax, nfft=nfft, window=window)
    k = n_bins(fmax, fs=fs, nperseg=nperseg, nfft=nfft)
    freqs, g = cross_spectral_matrix(
        signals, fs=fs, nperseg=nperseg, noverlap=noverlap, nbins=k + 1, window=window, nfft=nfft
    )
    return freqs[1:], g[1:]


def ordinary_coherence(g, a: int, b: int):
    """Ordinary coherence ``|G_ab|^2 / (G_aa G_bb)`` ``(F,)`` of channels ``a`` and ``b``."""
    return jnp.abs(g[:, a, b]) ** 2 / jnp.real(g[:, a, a] * g[:, b, b])


class ZError(NamedTuple):
    """The covariance of ``Z`` that a Welch average implies (a pytree; docs/estimation.md §3).

    At one bin, ``Cov(Z_ij, Z_i'j') = E[dZ_ij conj(dZ_i'j')] = force[i, i'] * position[j, j']``:

    - ``force`` ``(F, 2, 2)`` complex [N^2/Hz]: cross-spectral density of the residual
      ``e = F_h - Z x`` (what the inputs do not explain), divided by ``1 - 2 kappa / S`` for
      the averages that fitting ``Z`` used up (``S`` segments, ``kappa = bin_corr_raw``);
    - ``position`` ``(F, 2, 2)`` complex [Hz/m^2]: ``conj((G_xu G_uu^-1 G_ux)^-1) / n_eff``,
      the inverse of the input-coherent position spectrum over the effective number of
      averages ``n_eff = S / kappa`` (overlapping segments are not independent).

    Between bins ``d`` apart the covariance is ``bin_corr[d]`` times the geometric mean of
    the two bins' (the window's spectral leakage and the segments' overlap correlate them;
    ``bin_corr[0] = 1``). ``dof`` ``(F,)``: degrees of freedom of ``force`` at each bin (a
    scaled chi-square), NaN when the record has too few segments to estimate it.
    ``n_eff`` (scalar): the effective number of independent averages ``S / kappa``. Under
    ``jax.vmap`` every field gains the batch axis.
    """

    force: jnp.ndarray
    position: jnp.ndarray
    bin_corr: jnp.ndarray
    dof: jnp.ndarray
    n_eff: jnp.ndarray


def bin_correlation(n_seg: int, *, nperseg: int, noverlap: int, window="hann", nfft: int | None = None):
    """``r(d)``, ``d = 0 .. D`` bins: how much the Welch average correlates errors ``d`` bins apart.

    A white error's windowed DFTs correlate between segments ``l`` steps apart and bins
    ``d`` apart by ``rho_l(d) = sum_m w_m w_(m + l step) exp(-2 pi j d m / nfft) / sum_m w_m^2``;
    an error of ``Z`` (a product of the error's and the input's DFTs, both locally white)
    then by ``r(d) = sum_l (1 - |l| / S) |rho_l(d)|^2`` (``S = n_seg``), relative to ``1 / S``
    of one segment. ``r(0) = kappa``: ``S / kappa`` is the effective number of independent
    averages (about 1.84 for Hann with 75% overlap). ``D = 8 ceil(nfft / nperseg)``.
    Returns ``(D + 1,)`` float64.
    """
    nfft = nperseg if nfft is None else nfft
    w = welch_window(window, nperseg)
    step = nperseg - noverlap
    n_bins_corr = 8 * (-(-nfft // nperseg)) + 1
    r = jnp.zeros(n_bins_corr)
    norm = jnp.sum(w**2) ** 2
    for lag in range(min(n_seg - 1, (nperseg - 1) // step) + 1):
        d = lag * step
        spec = jnp.fft.fft(w[: nperseg - d] * w[d:], n=nfft)[:n_bins_corr]
        r = r + (1.0 if lag == 0 else 2.0 * (1.0 - lag / n_seg)) * jnp.abs(spec) ** 2 / norm
    return r


def z_error(g, z, n_seg: int, *, nperseg: int, noverlap: int, window="hann", nfft: int | None = None) -> ZError:
    """The ``ZError`` of ``z = T R^-1`` ``(F, 2, 2)`` from the band's cross-spectral matrix ``g``
    ``(F, 6, 6)`` (channels ``f_delta, x, fh``, as ``band_spectra``) of ``n_seg`` segments.

    First order in the error: ``dZ = G_eu G_xu^-1`` with ``e = F_h - Z x`` (``G_ab = E[A conj B]``),
    so ``Cov(dZ_i., dZ_i'.) = G_ee,ii' conj(G_xu^-1)^H conj(G_uu) conj(G_xu^-1) kappa / S`` for
    locally white spectra (H1 variance, Bendat & Piersol section 9.3, with overlapping
    segments). The residual spectrum is measured at the fitted ``Z``: that removes about
    ``2 kappa`` of the ``S`` averages, which ``force`` puts back.
    """
    gt = jnp.swapaxes(g, -1, -2)  # gt[a, b] = E[A conj(B)]: the textbook convention
    guu, gxu, gxx = gt[:, 0:2, 0:2], gt[:, 2:4, 0:2], gt[:, 2:4, 2:4]
    gff, gfx = gt[:, 4:6, 4:6], gt[:, 4:6, 2:4]

    def herm(a):
        return jnp.conj(jnp.swapaxes(a, -1, -2))

    gee = gff - z @ herm(gfx) - gfx @ herm(z) + z @ gxx @ herm(z)
    c = _inv2(gxu)
    p = herm(c) @ guu @ c  # (G_xu G_uu^-1 G_ux)^-1
    # tr(G_xx,coherent^-1 G_xx): 2 when the position is all explained by the inputs, more when not
    t_x = jnp.real(jnp.trace(p @ gxx, axis1=-2, axis2=-1))
    r = bin_correlation(n_seg, nperseg=nperseg, noverlap=noverlap, window=window, nfft=nfft)
    kappa = r[0]
    # E[G_ee] = G_e (S - 2 q kappa + kappa t_x) / S: fitting Z took 2 q kappa averages and the
    # error of Z times x gave back kappa t_x (docs/estimation.md section 3)
    left = n_seg - 2.0 * N_INPUTS * kappa + kappa * t_x
    left = jnp.where(n_seg > N_INPUTS * kappa, left, jnp.nan)  # too few segments: no error model
    force = 0.5 * (gee + herm(gee)) * (n_seg / left)[:, None, None]
    return ZError(
        force=force,
        position=jnp.conj(0.5 * (p + herm(p))) * (kappa / n_seg),
        bin_corr=r / kappa,
        dof=2.0 * left**2 / (n_seg * kappa),
        n_eff=n_seg / kappa,
    )


def n_bins(fmax: float, *, fs: float, nperseg: int, nfft: int | None = None) -> int:
    """Number of bins with ``0 < f <= fmax`` (122 for the paper's settings); bins are
    ``fs / nfft`` apart (``nfft`` defaults to ``nperseg``)."""
    return int(fmax * (nperseg if nfft is None else nfft) / fs + 1e-9)
