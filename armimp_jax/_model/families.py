"""Perturbation families as values: parameters that generate the ``(N, 2)`` force ``F_Delta``.

A family is an immutable pytree with ``signal(key, n_samples, period)``, the force [N] at
one sample per control period. Its ``shape`` field (a ``(2, K)`` array of non-negative
weights, one row per axis) is what experiment design moves (``_design/design.py``);
``rms`` [N] (per axis) sets the level, exactly. Three families:

- ``PaperNoise``: the paper's perturbation (``perturbation``: filtered uniform noise scaled
  to a peak), for comparison; it has no shape to design.
- ``ShapedNoise``: Gaussian noise whose amplitude spectrum is a piecewise-linear function
  of frequency through ``knots`` [Hz] with values ``shape``, periodic over the record
  (shaped by FFT), independent per axis (so the two inputs stay incoherent, as the MIMO
  Welch estimator needs), scaled to ``rms``; optionally gated into bursts (``duty`` of
  every ``burst`` seconds, both axes together): at the same RMS a burst's force is
  ``1 / sqrt(duty)`` larger, which moves joints that friction holds still under
  continuous noise (docs/experiment_design.md).
- ``Multisine``: a sum of cosines per axis at ``freqs`` [Hz] with amplitudes in proportion to
  ``shape`` and ``phases`` (Schroeder's by default: a low crest factor), scaled to ``rms``.
  The two axes take interleaved frequencies (``multisine``), because one frequency
  excited on both axes gives a rank-one input spectrum, from which no 2x2 impedance can be
  estimated.

Single-record functions; ``jax.grad`` flows through ``shape`` and ``rms``.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from .._checks import as_float64, as_param, check_int, is_concrete
from .._pytree import params
from .perturbation import PERTURBATION_CUTOFF, perturbation
from .timing import SAMPLE_RATE

NYQUIST = SAMPLE_RATE / 2.0


def _sized(name, x, rows, where):
    """``x`` as a float64 parameter with ``rows`` leading axes' sizes fixed (``None``: any) and
    one free trailing axis."""
    shape = tuple(np.shape(x))
    want = tuple(shape[i] if r is None else r for i, r in enumerate(rows)) if len(shape) == len(rows) else None
    if want is None:
        raise ValueError(f"{where}: {name} must have {len(rows)} axes, got shape {shape}")
    return as_param(name, x, want, where=where)


def _positive_rms(rms, where):
    rms = as_param("rms [N]", rms, (2,), where=where, broadcast=True)
    if is_concrete(rms) and not np.all(np.asarray(rms) > 0):
        raise ValueError(f"{where}: rms must be > 0 N per axis, got {np.asarray(rms).tolist()}")
    return rms


def _check_shape(shape, k: int, where: str):
    shape = as_param("shape", shape, (2, k), where=where)
    if is_concrete(shape):
        s = np.asarray(shape)
        if np.any(s < 0) or not np.all(s.max(axis=1) > 0):
            raise ValueError(f"{where}: shape must be >= 0 with a positive entry per axis, got {s.tolist()}")
    return shape


def _check_band(freqs, where: str, name: str):
    f = np.asarray(freqs, dtype=float)
    if f.size == 0 or np.any(~np.isfinite(f)) or np.any(f < 0) or np.any(f >= NYQUIST):
        raise ValueError(
            f"{where}: {name} must lie in [0, {NYQUIST:g}) Hz (below the control rate's Nyquist), got {f.tolist()}"
        )
    return f


def _scale_to_rms(s, rms):
    return s * (rms / jnp.sqrt(jnp.mean(s * s, axis=0)))[None, :]


@params(static=("cutoff",))
class PaperNoise:
    """The paper's perturbation (``perturbation``): uniform noise through an 8th-order
    Butterworth at ``cutoff`` [Hz], scaled so that each axis peaks at ``peak`` [N] ``(2,)``."""

    peak: jnp.ndarray
    cutoff: float = PERTURBATION_CUTOFF

    def __post_init__(self):
        object.__setattr__(self, "peak", as_param("peak [N]", self.peak, (2,), where="PaperNoise", broadcast=True))
        _check_band([self.cutoff], "PaperNoise", "cutoff")

    def signal(self, key, n_samples: int, period: float = 1.0 / SAMPLE_RATE):
        return perturbation(key, n_samples, self.peak, cutoff=self.cutoff)


GATE_RAMP = 0.02  # [s] rise and fall of a burst's gate: a smooth gate adds little leakage


@params(static=("duty", "burst"))
class ShapedNoise:
    """Gaussian noise with a designed amplitude spectrum, per axis, optionally in bursts.

    Args:
        knots: ``(K,)`` [Hz], increasing, below the Nyquist frequency of the control rate.
        shape: ``(2, K)`` relative amplitude spectrum at the knots (>= 0), linear between them
            and zero outside ``[knots[0], knots[-1]]``.
        rms: ``(2,)`` [N] RMS per axis of the signal (over the record, gate included).
        duty: fraction of time the noise is on, in ``(0, 1]`` (default 1: continuous). Static.
        burst: the gate's period [s] (default 2), ``> 0``: on for ``duty * burst`` seconds of
            each, with ``GATE_RAMP`` edges, both axes together, at a phase drawn from the
            key. Static.
    """

    knots: jnp.ndarray
    shape: jnp.ndarray
    rms: jnp.ndarray
    duty: float = 1.0
    burst: float = 2.0

    def __post_init__(self):
        w = "ShapedNoise"
        for name, v, ok, allowed in (
            ("duty", self.duty, lambda v: 0 < v <= 1, "(0, 1]"),
            ("burst", self.burst, lambda v: 0 < v < math.inf, "(0, inf) s"),
        ):
            if isinstance(v, bool) or not isinstance(v, (int, float, np.floating, np.integer)) or not ok(v):
                raise ValueError(f"{w}: {name} must lie in {allowed}, got {v!r}")
            object.__setattr__(self, name, float(v))
        if self.duty < 1 and self.duty * self.burst <= 2 * GATE_RAMP:
            raise ValueError(
                f"{w}: a burst of duty * burst = {self.duty * self.burst:g} s is no longer than its two "
                f"{GATE_RAMP:g} s edges; raise duty or burst"
            )
        knots = _sized("knots [Hz]", self.knots, (None,), w)
        if is_concrete(knots):
            k = _check_band(knots, w, "knots")
            if k.size < 2 or np.any(np.diff(k) <= 0):
                raise ValueError(f"{w}: knots must be at least two increasing frequencies, got {k.tolist()}")
        object.__setattr__(self, "knots", knots)
        object.__setattr__(self, "shape", _check_shape(self.shape, knots.shape[0], w))
        object.__setattr__(self, "rms", _positive_rms(self.rms, w))

    def amplitude(self, freq):
        """The relative amplitude spectrum at ``freq`` [Hz] ``(F,)``: ``(F, 2)``."""
        inside = (freq >= self.knots[0]) & (freq <= self.knots[-1])
        return jnp.stack([jnp.where(inside, jnp.interp(freq, self.knots, self.shape[a]), 0.0) for a in range(2)], 1)

    def signal(self, key, n_samples: int, period: float = 1.0 / SAMPLE_RATE):
        n_samples = check_int("n_samples", n_samples, minimum=2)
        if is_concrete(self.knots):  # a band between two FFT bins would give no signal (0/0 in the scaling)
            f = np.fft.rfftfreq(n_samples, period)
            k = np.asarray(self.knots)
            if not np.any((f >= k[0]) & (f <= k[-1])):
                raise ValueError(
                    f"ShapedNoise: no frequency of a {n_samples * period:g} s record (spacing "
                    f"{1 / (n_samples * period):g} Hz) lies in the band {k[0]:g}-{k[-1]:g} Hz; "
                    "widen it or record longer"
                )
        return _shaped_signal(self, key, n_samples=n_samples, period=float(period))

    def gate(self, key, n_samples: int, period: float = 1.0 / SAMPLE_RATE):
        """The burst gate ``(N,)`` in ``[0, 1]``: 1 for ``duty`` of each ``burst`` period, with
        linear edges of ``GATE_RAMP`` seconds, starting at a phase drawn from ``key``."""
        t = jnp.arange(n_samples, dtype=jnp.float64) * period
        u = jnp.mod(t / self.burst + jax.random.uniform(key, dtype=jnp.float64), 1.0)  # phase in the period
        # signed distance [s] to the nearest edge of the on-interval [0, duty): > 0 inside
        inside = jnp.minimum(u, self.duty - u)
        outside = jnp.maximum(self.duty - u, u - 1.0)
        d = jnp.where(u < self.duty, inside, outside) * self.burst
        return jnp.clip(d / GATE_RAMP + 0.5, 0.0, 1.0)


@functools.partial(jax.jit, static_argnames=("n_samples", "period"))
def _shaped_signal(family: ShapedNoise, key, *, n_samples: int, period: float):
    """``ShapedNoise.signal`` after its checks: one compiled program per record (op by op, each
    operation would compile on its own)."""
    white = jax.random.normal(key, (n_samples, 2), dtype=jnp.float64)
    freq = jnp.fft.rfftfreq(n_samples, period)
    shaped = jnp.fft.irfft(jnp.fft.rfft(white, axis=0) * family.amplitude(freq), n=n_samples, axis=0)
    if family.duty < 1:
        shaped = shaped * family.gate(jax.random.fold_in(key, 1), n_samples, period)[:, None]
    return _scale_to_rms(shaped, family.rms)


@params
class Multisine:
    """A sum of cosines per axis: ``sum_k a_ik cos(2 pi f_ik t + phi_ik)`` with ``a`` in
    proportion to ``shape`` and scaled to ``rms``.

    Args:
        freqs: ``(2, K)`` [Hz] per axis, below the Nyquist frequency of the control rate.
        shape: ``(2, K)`` relative amplitudes (>= 0).
        phases: ``(2, K)`` [rad].
        rms: ``(2,)`` [N] RMS per axis (over the record).
    """

    freqs: jnp.ndarray
    shape: jnp.ndarray
    phases: jnp.ndarray
    rms: jnp.ndarray

    def __post_init__(self):
        w = "Multisine"
        freqs = _sized("freqs [Hz]", self.freqs, (2, None), w)
        if is_concrete(freqs):
            _check_band(freqs, w, "freqs")
        k = freqs.shape[1]
        object.__setattr__(self, "freqs", freqs)
        object.__setattr__(self, "shape", _check_shape(self.shape, k, w))
        object.__setattr__(self, "phases", as_param("phases [rad]", self.phases, (2, k), where=w))
        object.__setattr__(self, "rms", _positive_rms(self.rms, w))

    def signal(self, key=None, n_samples: int = 0, period: float = 1.0 / SAMPLE_RATE):
        n_samples = check_int("n_samples", n_samples, minimum=2)
        t = jnp.arange(n_samples, dtype=jnp.float64)[:, None, None] * period
        waves = self.shape[None] * jnp.cos(2.0 * jnp.pi * self.freqs[None] * t + self.phases[None])
        return _scale_to_rms(jnp.sum(waves, axis=-1), self.rms)


def schroeder_phases(shape) -> np.ndarray:
    """Schroeder's phases for relative amplitudes ``shape`` ``(2, K)``: ``phi_k = -2 pi sum_{l<k}
    (k - l) p_l`` with ``p`` the power fractions; a crest factor near 1.5-1.7 for flat spectra."""
    a = np.asarray(shape, dtype=float)
    p = a**2 / np.sum(a**2, axis=1, keepdims=True)
    k = np.arange(a.shape[1])
    return np.stack([-2.0 * np.pi * np.array([np.sum((i - k[:i]) * row[:i]) for i in k]) for row in p])


def multisine(freqs, rms, *, shape=None, phases=None, offset: float = 0.5) -> Multisine:
    """A ``Multisine`` on a frequency grid ``freqs`` ``(K,)`` [Hz]: axis x at ``freqs``, axis y at
    ``freqs + offset * spacing`` (interleaved, so each Welch bin holds a line of each axis whose
    relative phase turns from segment to segment: the 2x2 estimate stays well posed). ``shape``
    (default flat) ``(K,)`` or ``(2, K)``; ``phases`` default Schroeder's; ``rms`` [N] scalar or
    ``(2,)``."""
    f = np.asarray(as_float64("freqs", freqs, where="multisine"), dtype=float)
    if f.ndim != 1 or f.size < 1 or np.any(np.diff(f) <= 0):
        raise ValueError(f"multisine: freqs must be increasing frequencies (K,), got {f.tolist()}")
    spacing = float(np.min(np.diff(f))) if f.size > 1 else float(f[0])
    grid = np.stack([f, f + offset * spacing])
    _check_band(grid, "multisine", "freqs (with the y axis' offset)")
    a = np.ones((2, f.size)) if shape is None else np.broadcast_to(np.asarray(shape, dtype=float), (2, f.size))
    ph = schroeder_phases(a) if phases is None else np.broadcast_to(np.asarray(phases, dtype=float), (2, f.size))
    return Multisine(grid, a, ph, np.broadcast_to(np.asarray(rms, dtype=float), (2,)))


def crest_factor(signal) -> jnp.ndarray:
    """Peak over RMS per axis of a force record ``(N, 2)``."""
    return jnp.max(jnp.abs(signal), axis=0) / jnp.sqrt(jnp.mean(signal * signal, axis=0))
