"""Figures of a lab's recording, for both routes of ``sweeps/estimate_recording.py``.

- The Welch route (``study.recording.estimate_recording``): ``bode_figure`` (the estimate of ``Z`` and the fitted
  model; the estimate's phase drawn on the model's branch, ``phase_near``) and
  ``coherence_figure``.
- The model route (``study.recording.identify_recording``): ``position_figure``, ``residual_figure``,
  ``frf_figure`` and ``ellipse_figure`` (with ``ellipse_radius`` and ``stiffness_draws``).

Each returns a matplotlib ``Figure`` made without pyplot (no global figure state); the
caller saves it (``study.sweep.figures.save_figure``).
"""

from __future__ import annotations

import numpy as np
import scipy.signal
from matplotlib.figure import Figure
from matplotlib.ticker import NullFormatter

from ..._estimation.welch import welch_segments

ELEMENTS = ((0, 0), (0, 1), (1, 0), (1, 1))
AXES = ("x", "y")
OUTPUTS = {"x": ("x", "y"), "fh": ("fh_x", "fh_y")}  # output channels' names, per estimate field
ELLIPSE_DRAWS = 200


def phase_near(z, reference) -> np.ndarray:
    """Phase [deg] of ``z`` on the branch of ``reference`` (same shape, complex): the
    reference's continuous phase (unwrapped along axis 0 from its principal value) plus the
    principal angle of ``z / reference``, so within 180 deg of it. A noisy estimate's own
    unwrapped phase drifts by whole turns wherever the noise crosses the branch cut."""
    z, reference = np.asarray(z), np.asarray(reference)
    return np.degrees(np.unwrap(np.angle(reference), axis=0) + np.angle(z / reference))


def bode_figure(f, z, z_fit, *, title: str = "impedance Z: Welch estimate and fitted model"):
    """Magnitude [N/m] and phase [deg] of the four elements of ``z`` ``(F, 2, 2)`` (the
    estimate) and ``z_fit`` (the fitted model of the record, its acquisition included)
    against ``f`` [Hz]. The model's phase is continuous; the estimate's is drawn within 180
    deg of the model's (``phase_near``)."""
    f, z, z_fit = (np.asarray(a) for a in (f, z, z_fit))
    fig = Figure(figsize=(15, 7), layout="constrained")
    axes = fig.subplots(2, 4, sharex=True)
    phases = (phase_near(z, z_fit), np.degrees(np.unwrap(np.angle(z_fit), axis=0)))
    for col, (i, j) in enumerate(ELEMENTS):
        name = f"$Z_{{{AXES[i]}{AXES[j]}}}$ ($F_{{h,{AXES[i]}}}$ per ${AXES[j]}$)"
        for data, phase, style, label in zip(
            (z, z_fit), phases, ("-", "k--"), ("estimate $\\hat Z$", "fitted model"), strict=True
        ):
            axes[0, col].loglog(f, np.abs(data[:, i, j]), style, label=label)
            axes[1, col].semilogx(f, phase[:, i, j], style)
        axes[0, col].set_title(name)
        axes[1, col].set_xlabel("frequency [Hz]")
    axes[0, 0].set_ylabel("magnitude [N/m]")
    axes[1, 0].set_ylabel("phase [deg]")
    axes[0, 0].legend(fontsize=8)
    fig.suptitle(title, fontsize=11)
    return fig


def coherence_figure(est):
    """Multiple coherences of the four outputs (and the inputs' ordinary coherence), and
    partial coherences of the position and force outputs, against ``f`` [Hz]."""
    f = np.asarray(est.f)
    fig = Figure(figsize=(15, 4.5), layout="constrained")
    axes = fig.subplots(1, 3, sharey=True)
    for field, names in OUTPUTS.items():
        mult = np.asarray(getattr(est, f"coh_multiple_{field}"))
        for k, name in enumerate(names):
            axes[0].semilogx(f, mult[:, k], label=name)
    axes[0].semilogx(f, np.asarray(est.coh_inputs), "k:", label="inputs (ordinary)")
    axes[0].set_title("multiple coherence (both inputs)")
    for ax, (field, names) in zip(axes[1:], OUTPUTS.items()):
        part = np.asarray(getattr(est, f"coh_partial_{field}"))
        for k, name in enumerate(names):
            for j, inp in enumerate(("f_delta_x", "f_delta_y")):
                ax.semilogx(f, part[:, k, j], label=f"{name} | {inp}")
        ax.set_title(f"partial coherence, {'position' if field == 'x' else 'force'} outputs")
    axes[0].set_ylabel("coherence [-]")
    for ax in axes:
        ax.set_xlabel("frequency [Hz]")
        ax.set_ylim(0.0, 1.05)
        ax.legend(fontsize=8)
    return fig


def position_figure(t, x, x_model, x0, vaf):
    """(a) The recorded hand displacement and the fitted model's noise-free one, per axis."""
    fig = Figure(figsize=(12, 5.5), layout="constrained")
    axes = fig.subplots(2, 1, sharex=True)
    for k, ax in enumerate(axes):
        ax.plot(t, 1e3 * (x[:, k] - x0[k]), lw=0.8, label="recorded")
        ax.plot(t, 1e3 * (x_model[:, k] - x0[k]), "k--", lw=0.8, label="model (noise-free)")
        ax.set_ylabel(f"{'xy'[k]} - {'xy'[k]}0 [mm]")
        ax.set_title(f"hand position {'xy'[k]}: VAF {vaf[k]:.2f} %", fontsize=10)
    axes[0].legend(fontsize=8)
    axes[-1].set_xlabel("time [s]")
    return fig


def residual_figure(fs, x, fh, x_model, fh_model):
    """(b) Welch PSDs of the position and force residuals, with the recorded signals' for scale."""
    nperseg, _ = welch_segments(max(x.shape[0] // 2, 64))  # half the estimate's segments: more averages, smoother
    fig = Figure(figsize=(12, 4.5), layout="constrained")
    axes = fig.subplots(1, 2)
    for ax, (rec_, mod, what, unit) in zip(axes, ((x, x_model, "position", "m"), (fh, fh_model, "force", "N"))):
        for k in range(2):
            f, p_res = scipy.signal.welch(rec_[:, k] - mod[:, k], fs=fs, nperseg=nperseg)
            _, p_rec = scipy.signal.welch(rec_[:, k], fs=fs, nperseg=nperseg)
            (line,) = ax.loglog(f[1:], p_res[1:], lw=0.9, label=f"residual {'xy'[k]}")
            ax.loglog(f[1:], p_rec[1:], ":", color=line.get_color(), lw=0.8, label=f"recorded {'xy'[k]}")
        ax.set_title(f"{what}: recorded minus model", fontsize=10)
        ax.set_xlabel("frequency [Hz]")
        ax.set_ylabel(f"PSD [{unit}^2/Hz]")
        ax.legend(fontsize=8)
    return fig


def frf_figure(f_model, z_model, measured=None, z_classical=None):
    """(c) ``|Z_ij|`` [N/m] of the identified arm's ``M s^2 + B s + K`` (and of the classical
    fit's arm) at ``f_model`` [Hz], over the Welch estimate ``measured = (f, Z)`` if given."""
    fig = Figure(figsize=(15, 4.3), layout="constrained")
    axes = fig.subplots(1, 4, sharex=True)
    for ax, (i, j) in zip(axes, ELEMENTS):
        if measured is not None:
            ax.loglog(measured[0], np.abs(measured[1][:, i, j]), ".-", ms=3, lw=0.8, label="Welch estimate")
        ax.loglog(f_model, np.abs(z_model[:, i, j]), "k-", lw=1.2, label="identified model")
        if z_classical is not None:
            ax.loglog(f_model, np.abs(z_classical[:, i, j]), "--", lw=1, label="classical fit")
        ax.set_title(f"$|Z_{{{'xy'[i]}{'xy'[j]}}}|$", fontsize=10)
        ax.set_xlabel("frequency [Hz]")
        ax.xaxis.set_minor_formatter(NullFormatter())  # no crowded minor labels on short bands
        ax.yaxis.set_minor_formatter(NullFormatter())
    axes[0].set_ylabel("magnitude [N/m]")
    axes[0].legend(fontsize=8)
    fig.suptitle("impedance magnitude: the identified arm and the classical fit over the Welch estimate", fontsize=11)
    return fig


def ellipse_radius(k, phi) -> np.ndarray:
    """Radius [N/m] at angles ``phi`` of the stiffness ellipse of ``k`` ``(..., 2, 2)``: the curve
    of ``K_s d`` for unit displacements ``d``, ``K_s`` the symmetric part; ``(..., len(phi))``."""
    k = np.asarray(k, dtype=float)
    a, b, d = k[..., 0, 0, None], 0.5 * (k[..., 0, 1, None] + k[..., 1, 0, None]), k[..., 1, 1, None]
    c, s = np.cos(phi), np.sin(phi)  # |K_s^-1 u| = |adj(K_s) u| / |det K_s|
    return np.abs(a * d - b * b) / np.hypot(d * c - b * s, a * s - b * c)


def stiffness_draws(res, n: int = ELLIPSE_DRAWS, seed: int = 0) -> np.ndarray | None:
    """``n`` draws of ``K`` ``(n, 2, 2)`` from the normal approximation (the estimate and the
    covariance of its entries); ``None`` when ``arm.stiffness`` is not free."""
    labels = [f"arm.stiffness[{i},{j}]" for i, j in ELEMENTS]
    if not all(lab in res.labels for lab in labels):
        return None
    idx = [res.labels.index(lab) for lab in labels]
    w, v = np.linalg.eigh(np.asarray(res.covariance)[np.ix_(idx, idx)])
    z = np.random.default_rng(seed).standard_normal((n, 4))
    k = np.asarray(res.values["arm.stiffness"]).reshape(4) + (z * np.sqrt(np.clip(w, 0.0, None))) @ v.T
    return k.reshape(n, 2, 2)


def ellipse_figure(k, draws=None, k_classical=None):
    """(d) The stiffness ellipse of ``k`` with the 95% band of ``draws`` over angle, and the
    classical fit's ellipse."""
    phi = np.linspace(0.0, 2.0 * np.pi, 361)
    fig = Figure(figsize=(7.5, 6), layout="constrained")
    ax = fig.subplots()
    if draws is not None:
        lo, hi = np.nanpercentile(ellipse_radius(draws, phi), [2.5, 97.5], axis=0)
        ring = np.r_[hi, lo[::-1]], np.r_[phi, phi[::-1]]
        ax.fill(ring[0] * np.cos(ring[1]), ring[0] * np.sin(ring[1]), alpha=0.3, lw=0, label="95% band")
    r = ellipse_radius(k, phi)
    ax.plot(r * np.cos(phi), r * np.sin(phi), "k-", label="identified K")
    if k_classical is not None:
        rc = ellipse_radius(k_classical, phi)
        ax.plot(rc * np.cos(phi), rc * np.sin(phi), "--", label="classical fit")
    ax.set_aspect("equal", adjustable="datalim")  # a square box whatever the ellipse's shape
    ax.set_xlabel("force x per unit displacement [N/m]")
    ax.set_ylabel("force y per unit displacement [N/m]")
    held = "" if draws is not None else " (K held: no band)"
    ax.set_title(f"stiffness ellipse (symmetric part of K){held}", fontsize=10)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
    ax.grid(alpha=0.3)
    return fig
