"""The five-bar's inverse dynamics as a least squares in its inertia constants and each joint's
static friction (IDIM-LS; Gautier and Khalil; Swevers et al.): the regressor, the zero-phase
filter that both sides of it pass through, the samples it keeps, the correction of the
accelerations' noise and the Newey-West covariance. Host code (NumPy, SciPy): a least squares
of one pass over the samples, no simulation. ``calibration.py`` is its public face.

Per sample, with ``d = q1 - q2`` (docs/model.md sections 2 and 4b), the joint torques are

    tau1 = c1 qdd1 + c2 (cos d qdd2 + sin d qd2^2) + tau_c1 sign(qd1) + viscous1 qd1
    tau2 = c2 (cos d qdd1 - sin d qd1^2) + c3 qdd2 + tau_c2 sign(qd2) + viscous2 qd2

linear in ``theta = (c1, c2, c3, tau_c1, tau_c2, viscous1, viscous2)``. The rates are central
differences of the raw angles, and the torque at sample ``k`` is the mean of the commands held
over the two periods a central second difference spans, ``(tau_k-1 + tau_k) / 2``.

**Parallel filtering.** Raw second differences are mostly noise (an encoder count's step at 1
kHz), so every column of the regressor and the torque pass through one zero-phase low-pass
``F``: ``F[tau] = F[Y] theta`` holds wherever ``Y theta = tau`` holds over ``F``'s support, so
the filter's droop in the band costs precision, never bias. ``F`` is a Hamming-windowed FIR of
one cut-off period each side (``fir``), run forward and backward (``scipy.signal.filtfilt``):
its support is finite, ``support(F)`` samples each side, so a kept sample sees no sample where
the static law fails. (An IIR filter's tail carried each stick-slip event's unmodelled torque
into its neighbours: measured, a bias of several SEs on the inertias.)

**Kept samples.** A joint's row at sample ``k`` is kept where that joint's filtered rate is at
least ``min_rate`` over ``F``'s whole support about ``k`` (and ``F``'s start-up is past): near
zero rate the Coulomb sign is undefined and LuGre's bristles and Stribeck curve act.

**The accelerations' noise.** ``F[Y]``'s acceleration columns carry the filtered noise of the
angles: least squares with a noisy regressor shrinks the inertias (errors in variables). The
angle noise's variance, white, is read from the angles above a quarter of the sample rate over
the kept samples (``angle_noise``: an encoder count ``D`` gives ``D^2 / 12``); its share of
``F[Y]^T F[Y]`` is subtracted (bias-compensated least squares), and of the scores with it.

**The covariance.** The residuals pass through ``F`` and the loop: they are coloured, so the
scores ``F[Y]_k^T e_k`` are summed with Bartlett weights over ``lag`` samples (Newey and West,
1987), ``lag`` by Andrews' (1991) AR(1) plug-in rule for the Bartlett kernel, per recording
(recordings are independent).
"""

from __future__ import annotations

import math

import numpy as np
import scipy.signal

N_THETA = 7  # c1, c2, c3, tau_c (2), viscous (2)
INERTIA, COULOMB, VISCOUS = slice(0, 3), slice(3, 5), slice(5, 7)
# The angles' noise is read above this fraction of the sample rate (a quarter: far above any
# motion a perturbation drives, where an encoder's steps are white).
NOISE_BAND = 0.25
NOISE_TAPS = 31
BAND_POWER = 0.99  # the command's band: the frequency below which this share of its power lies


def fir(cutoff: float, fs: float) -> np.ndarray:
    """The low-pass ``F``'s taps: Hamming-windowed, cut-off ``cutoff`` [Hz], one cut-off period
    each side (``2 round(fs / (2 cutoff)) + 1`` taps, at least 5)."""
    half = max(2, int(round(fs / (2.0 * cutoff))))
    return scipy.signal.firwin(2 * half + 1, cutoff, fs=fs, window="hamming")


def support(taps) -> int:
    """Samples each side that ``filtfilt`` of ``taps`` reaches."""
    return len(taps) - 1


def zero_phase(taps, a):
    """``F[a]`` along axis 0: ``taps`` forward and backward (zero phase)."""
    return scipy.signal.filtfilt(taps, [1.0], a, axis=0)


def rates(q, period: float):
    """Central differences ``(qd, qdd)`` of ``q`` ``(N, 2)`` (the ends copied from their
    neighbours: they are never kept)."""
    qd, qdd = np.empty_like(q), np.empty_like(q)
    qd[1:-1] = (q[2:] - q[:-2]) / (2.0 * period)
    qdd[1:-1] = (q[2:] - 2.0 * q[1:-1] + q[:-2]) / period**2
    for a in (qd, qdd):
        a[0], a[-1] = a[1], a[-2]
    return qd, qdd


def regressor(q, qd, qdd):
    """``Y`` ``(N, 2, 7)``: joint rows, columns ``theta``'s (module docstring)."""
    d = q[:, 0] - q[:, 1]
    cd, sd = np.cos(d), np.sin(d)
    y = np.zeros(q.shape[:1] + (2, N_THETA))
    y[:, 0, 0] = qdd[:, 0]
    y[:, 0, 1] = cd * qdd[:, 1] + sd * qd[:, 1] ** 2
    y[:, 1, 1] = cd * qdd[:, 0] - sd * qd[:, 0] ** 2
    y[:, 1, 2] = qdd[:, 1]
    for j in range(2):
        y[:, j, COULOMB.start + j] = np.sign(qd[:, j])
        y[:, j, VISCOUS.start + j] = qd[:, j]
    return y


def aligned_torque(tau):
    """The torque a central second difference at ``k`` sees under a zero-order hold:
    ``(tau_k-1 + tau_k) / 2`` (the first sample kept as it is: never kept)."""
    out = tau.copy()
    out[1:] = 0.5 * (tau[1:] + tau[:-1])
    return out


def kept(rate_f, min_rate: float, reach: int):
    """``(N, 2)`` bool: the joint's filtered rate is at least ``min_rate`` over ``+-reach``
    samples, and the sample is ``3 reach`` from the ends (the filter's start-up)."""
    slow = (np.abs(rate_f) < min_rate).astype(float)
    window = np.ones(2 * reach + 1)
    near = np.stack([np.convolve(slow[:, j], window, mode="same") > 0 for j in range(2)], axis=1)
    keep = ~near
    keep[: 3 * reach] = False
    keep[-3 * reach :] = False
    return keep


def angle_noise(q, keep, fs: float):
    """Each joint's angle-noise variance [rad^2] from ``q`` above ``NOISE_BAND fs`` over the
    samples ``keep`` marks (a white noise's share of that band, through the high-pass's gain)."""
    taps = scipy.signal.firwin(NOISE_TAPS, NOISE_BAND * fs, fs=fs, pass_zero=False)
    high = zero_phase(taps, q)
    gain = float(np.sum(zero_phase(taps, _impulse(4 * NOISE_TAPS)) ** 2))
    return np.array([np.var(high[keep[:, j], j]) if keep[:, j].any() else 0.0 for j in range(2)]) / gain


def _impulse(half: int):
    out = np.zeros(2 * half + 1)
    out[half] = 1.0
    return out


def noise_gains(taps, period: float):
    """``(g_d, g_dd)``: the variance of ``F[qd]`` and ``F[qdd]`` per unit variance of white noise
    on the angles."""
    d, dd = rates(_impulse(4 * len(taps))[:, None], period)
    return float(np.sum(zero_phase(taps, d) ** 2)), float(np.sum(zero_phase(taps, dd) ** 2))


def noise_share(q, noise, gains):
    """``(N, 2, 7, 7)``: each row's expected outer product of the regressor's noise (the
    acceleration and rate columns; the joints' noise independent, cos d slow over ``F``)."""
    g_d, g_dd = gains
    cd2 = np.cos(q[:, 0] - q[:, 1]) ** 2
    out = np.zeros(q.shape[:1] + (2, N_THETA, N_THETA))
    out[:, 0, 0, 0] = noise[0] * g_dd
    out[:, 0, 1, 1] = cd2 * noise[1] * g_dd
    out[:, 1, 1, 1] = cd2 * noise[0] * g_dd
    out[:, 1, 2, 2] = noise[1] * g_dd
    for j in range(2):
        out[:, j, VISCOUS.start + j, VISCOUS.start + j] = noise[j] * g_d
    return out


def andrews_lag(scores) -> int:
    """Andrews' (1991) AR(1) plug-in lag for the Bartlett kernel, ``1.1447 (alpha N)^(1/3)``, from
    each column's AR(1) fit (columns weighted alike), at least 1 and below ``N / 2``."""
    n = scores.shape[0]
    num = den = 0.0
    for x in scores.T:
        lagged = float(x[:-1] @ x[:-1])
        if lagged <= 0:
            continue
        rho = min(float(x[1:] @ x[:-1]) / lagged, 0.999)
        s2 = float(np.var(x[1:] - rho * x[:-1]))
        num += 4.0 * rho**2 * s2**2 / ((1.0 - rho) ** 6 * (1.0 + rho) ** 2)
        den += s2**2 / (1.0 - rho) ** 4
    alpha = num / den if den > 0 else 0.0
    return int(min(max(1, math.ceil(1.1447 * (alpha * n) ** (1.0 / 3.0))), n // 2 - 1))


def newey_west(scores, lag: int):
    """``sum_l w_l (G_l + G_l^T)``, ``G_l = sum_k s_k s_k-l^T``, Bartlett ``w_l = 1 - l / (lag + 1)``
    (``w_0 = 1``, counted once): the long-run covariance of the scores' sum ``(N, p)``."""
    out = scores.T @ scores
    for lag_l in range(1, lag + 1):
        g = scores[lag_l:].T @ scores[:-lag_l]
        out += (1.0 - lag_l / (lag + 1.0)) * (g + g.T)
    return out


def command_band(tau, fs: float) -> float:
    """The frequency [Hz] below which ``BAND_POWER`` of the command's power lies (its mean
    removed; both columns)."""
    f, p = scipy.signal.welch(tau - tau.mean(axis=0), fs=fs, nperseg=min(4096, tau.shape[0]), axis=0)
    total = np.cumsum(p.sum(axis=1))
    return float(f[min(np.searchsorted(total / total[-1], BAND_POWER), f.size - 1)])


class Rows:
    """One recording's filtered rows: ``y`` ``(N, 2, 7)``, ``tau`` ``(N, 2)``, ``keep`` ``(N, 2)``,
    the regressor's noise share ``noise`` ``(N, 2, 7, 7)`` and the angle noise ``variance``
    ``(2,)`` [rad^2]."""

    def __init__(self, y, tau, keep, noise, variance):
        self.y, self.tau, self.keep, self.noise, self.variance = y, tau, keep, noise, variance

    def normal(self):
        """``(H, g)`` of the kept rows, ``H`` less the noise's share."""
        k = self.keep.astype(float)
        h = np.einsum("nip,niq,ni->pq", self.y, self.y, k) - np.einsum("nipq,ni->pq", self.noise, k)
        return h, np.einsum("nip,ni,ni->p", self.y, self.tau, k)

    def residual(self, theta):
        """``(N, 2)`` the kept rows' residuals (zero where left out)."""
        return (self.tau - self.y @ theta) * self.keep

    def scores(self, theta):
        """``(N, 7)``: each sample's share of the estimating equation, noise-compensated."""
        e = self.residual(theta)
        return np.einsum("nip,ni->np", self.y, e) + np.einsum("nipq,q,ni->np", self.noise, theta, self.keep)


def rows(q, tau, period: float, taps, min_rate: float, noise=None) -> Rows:
    """The filtered rows of one recording: angles ``q`` and motor torques ``tau`` ``(N, 2)``
    (held over each period), through ``F`` (``taps``); ``noise``: the angles' noise variance
    ``(2,)`` [rad^2], ``None`` to read it from ``q``."""
    qd, qdd = rates(q, period)
    y = zero_phase(taps, regressor(q, qd, qdd))
    keep = kept(zero_phase(taps, qd), min_rate, support(taps))
    variance = angle_noise(q, keep, 1.0 / period) if noise is None else np.asarray(noise, dtype=float)
    share = noise_share(q, variance, noise_gains(taps, period))
    return Rows(y, zero_phase(taps, aligned_torque(tau)), keep, share, variance)


def noise_fraction(recordings: list[Rows]):
    """``(3,)``: the share of each inertia column's sum of squares that is the angles' noise
    (what the compensation removes)."""
    k = [r.keep.astype(float) for r in recordings]
    total = sum(np.einsum("nip,ni->p", r.y**2, w) for r, w in zip(recordings, k, strict=True))
    noise = sum(np.einsum("nipp,ni->p", r.noise, w) for r, w in zip(recordings, k, strict=True))
    return (noise / total)[INERTIA]


def solve(recordings: list[Rows]):
    """``(theta, covariance, lags)``: the bias-compensated least squares over every recording's
    kept rows and its Newey-West sandwich (one lag per recording)."""
    normal = [r.normal() for r in recordings]
    h, g = sum(n[0] for n in normal), sum(n[1] for n in normal)
    theta = np.linalg.solve(h, g)
    meat, lags = np.zeros_like(h), []
    for r in recordings:
        s = r.scores(theta)  # zero where both joints are left out: gaps in the sum, not in time
        lags.append(andrews_lag(s))
        meat += newey_west(s, lags[-1])
    h_inv = np.linalg.inv(h)
    return theta, h_inv @ meat @ h_inv, tuple(lags)
