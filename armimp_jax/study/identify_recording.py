"""The model route for a lab's own recording: a TOML config -> the starting ``Trial`` and
``identify``'s options, the fit through the closed-loop model, its results on disk.

- ``read_identify_config(path)``: the TOML, read and checked (``config.read_config``; plain
  values; no simulation).
  Every unknown section or key, missing section or key, wrong type or shape and unknown
  parameter name is an ``IdentifyConfigError`` (a ``ValueError``) with one line naming the
  key and what is allowed.
- ``build_model(config)``: the starting ``Trial`` and the keyword arguments of ``identify``
  (the constructors' own range checks come back as ``IdentifyConfigError`` naming the section).
- ``check_rate(fs, model)``: a recording not sampled at the trial's control rate is refused.
- ``run(rec, model, options)``: ``identify`` on a loaded recording (``study.recording``).
- ``trust_warnings``, ``report_lines``: where the fit cannot be trusted, and what a script prints.
- ``write_results``: ``identification.json`` (strict), ``identification.csv`` and four figures.

The keys, units and defaults are in docs/identify_recording.md.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import pathlib
from typing import NamedTuple

import jax
import numpy as np
import scipy.signal
from matplotlib.figure import Figure  # no pyplot: no global figure state
from matplotlib.ticker import NullFormatter

from .._estimation.welch import estimate
from .._identification.identify import identify
from .._identification.indirect import IDENTIFY_NUMERICS
from .._identification.layout import ARM_PARAMETERS, PARAMETERS
from .._model.sensors import Sensors
from .._simulate import simulate
from .._solver.numerics import METHODS, Numerics, named_solver
from .config import REQUIRED, TRIAL_SECTIONS, ConfigError, build_trial, read_config
from .figures import save_figure
from .recording import ELEMENTS, RecordingError
from .results import atomic_write_json, package_version, to_jsonable
from .tables import table, write_table

SECTIONS = {
    **TRIAL_SECTIONS,
    "identify": {
        "free": ("names", tuple(PARAMETERS), REQUIRED),
        "symmetric": ("names", tuple(ARM_PARAMETERS), []),
        "draws": ("int", 8, 64),
        "jacobian_draws": ("int", 1, 8),
        "max_steps": ("int", 1, 20),
        "seed": ("int", 0, 0),
        "method": ("text", METHODS, IDENTIFY_NUMERICS.method),  # identify's default numerics
        "substeps": ("int", 1, IDENTIFY_NUMERICS.substeps),
    },
}
REQUIRED_SECTIONS = ("controller", "arm", "friction", "identify")
CHANNELS = ("x", "y", "fh_x", "fh_y")  # identify's whiteness_p order: x1, x2, fh1, fh2
WHITENESS_P = 1e-3  # a Ljung-Box p-value below this: coloured residuals
VAF_MIN = 90.0  # [%] a channel the model explains less of: a poor fit
START_OFFSET = 1e-3  # [m] the recording's first position this far from [arm] endpoint: warn
ELLIPSE_DRAWS = 200


IdentifyConfigError = ConfigError  # the name this module's callers know


def read_identify_config(path) -> dict:
    """The config at ``path`` as plain values (lists for arrays), defaults filled in where
    they are the route's own (``None``: the library's default). Raises
    ``IdentifyConfigError`` with one line naming the file, the section and the key."""
    config = read_config(path, SECTIONS, REQUIRED_SECTIONS)
    ident = config["identify"]
    arm_free = [n for n in ident["free"] if n in ARM_PARAMETERS]
    not_free = [n for n in ident["symmetric"] if n not in arm_free]
    if not_free:
        raise IdentifyConfigError(
            f"{path}: [identify] symmetric names {not_free[0]!r}, which is not a free arm matrix; "
            f"allowed: {', '.join(arm_free) or 'none (free names no arm matrix)'}"
        )
    return config


def build_model(config: dict, *, where: str = "config") -> tuple:
    """``(Trial, options)`` from a config of ``read_identify_config``: the starting trial
    (``make_trial``) and ``identify``'s keyword arguments (``free``, ``symmetric``,
    ``numerics``, ``key``, ``draws``, ``jacobian_draws``, ``max_steps``). Needs float64."""

    model = build_trial(config, where=where)
    ident = config["identify"]
    numerics = Numerics(solver=named_solver(ident["method"]), substeps=ident["substeps"])
    options = dict(
        free=tuple(ident["free"]),
        symmetric=tuple(ident["symmetric"]),
        numerics=numerics,
        key=jax.random.key(ident["seed"]),
        draws=ident["draws"],
        jacobian_draws=ident["jacobian_draws"],
        max_steps=ident["max_steps"],
    )
    return model, options


def check_rate(fs: float, model) -> None:
    """Refuse (``RecordingError``) a sample rate ``fs`` [Hz] other than the trial's control rate."""
    rate = 1.0 / model.period
    if not math.isclose(fs, rate, rel_tol=1e-9):
        raise RecordingError(
            f"the recording's sample rate {fs:g} Hz is not the simulator's control rate {rate:g} Hz "
            f"(one sample per control period of {1e3 * model.period:g} ms): the model route compares "
            "the recording with the simulation sample by sample; resample it to that rate"
        )


def run(rec: dict, model, options: dict):
    """``identify(model, f_delta, x, fh, **options)`` for a loaded recording: an ``Identification``."""
    return identify(model, rec["f_delta"], rec["x"], rec["fh"], **options)


def _arm_matrices(res) -> dict:
    arm = res.trial.arm
    return {n: np.asarray(getattr(arm, n.split(".")[1])) for n in ARM_PARAMETERS}


def trust_warnings(res, rec: dict) -> list[str]:
    """Where the fit of ``res`` (an ``Identification``) cannot be trusted, one line each."""
    out = []
    if not res.converged:
        out.append(f"the fit did not converge ({res.message}): its values and SEs cannot be trusted")
    out += list(res.warnings)  # identify's own (identifiability, a model without noise)
    p = np.asarray(res.whiteness_p)
    low = [f"{c} (p = {v:.2g})" for c, v in zip(CHANNELS, p, strict=True) if not v >= WHITENESS_P]
    if low:
        out.append(
            f"the residuals are not white: {', '.join(low)} (Ljung-Box, p < {WHITENESS_P:g}); the model "
            "leaves structure in the recording (the person's own force, unmodelled dynamics or a wrong "
            "noise model), so read the SEs as approximate"
        )
    vaf = np.concatenate([res.vaf_position, res.vaf_force])
    poor = [f"{c} {v:.1f} %" for c, v in zip(CHANNELS, vaf, strict=True) if not v >= VAF_MIN]
    if poor:
        out.append(
            f"the model accounts for little of {', '.join(poor)} (VAF below {VAF_MIN:g} %): a poor fit; "
            "check the config (robot, controller gains, acquisition) and the recording's frame and signs"
        )
    offset = float(np.linalg.norm(np.asarray(rec["x"])[0] - np.asarray(res.trial.x0)))
    if offset > START_OFFSET:
        out.append(
            f"the recording starts {1e3 * offset:.1f} mm from [arm] endpoint, where the model starts at rest: "
            "the recording's positions must be in the model's world frame (origin at the shoulder)"
        )
    return out


class Entry(NamedTuple):
    """One estimated number: its parameter, index (``"0,1"``), label, unit, value, SE, 95%
    interval and the classical fit's value and SE (arm matrices only, else ``None``)."""

    parameter: str
    index: str
    label: str
    unit: str
    value: float
    se: float
    low95: float
    high95: float
    classical: float | None
    classical_se: float | None


def entries(res) -> list[Entry]:
    """Every entry of an ``Identification``, in the order of ``res.labels``."""
    out = []
    for name, value in res.values.items():
        value, se = np.asarray(value), np.asarray(res.se[name])
        low, high = (np.asarray(a) for a in res.interval(name))
        field, cls = name.split(".")[1], res.classical if name in ARM_PARAMETERS else None
        cval = None if cls is None else np.asarray(getattr(cls, field))
        cse = None if cls is None else np.asarray(getattr(cls, field + "_se"))
        for idx in np.ndindex(value.shape):
            index = ",".join(map(str, idx))
            numbers = [float(a[idx]) for a in (value, se, low, high)]
            classical = [None if a is None else float(a[idx]) for a in (cval, cse)]
            out.append(Entry(name, index, f"{name}[{index}]", PARAMETERS[name], *numbers, *classical))
    return out


def report_lines(res, warnings: list[str]) -> list[str]:
    """What the script prints: convergence, each entry as value +- SE (with the classical
    answer beside the arm's), VAF, whiteness, and every warning."""
    lines = ["converged" if res.converged else f"NOT CONVERGED: {res.message}"]
    lines.append(
        f"cost {res.cost:.6g} after {res.iterations} iterations, {res.time_s:.1f} s; estimates "
        "(value +- SE; 95% interval value +- 1.96 SE; arm matrices indexed [force axis, displacement axis]):"
    )
    for e in entries(res):
        beside = "" if e.classical is None else f"   (classical {e.classical:.4g})"
        lines.append(f"  {e.label} [{e.unit}]: {e.value:10.4g} +- {e.se:.3g}{beside}")
    vaf = np.concatenate([res.vaf_position, res.vaf_force])
    lines.append("VAF [%]: " + ", ".join(f"{c} {v:.2f}" for c, v in zip(CHANNELS, vaf, strict=True)))
    p = np.asarray(res.whiteness_p)
    lines.append(
        "residual whiteness (Ljung-Box p): " + ", ".join(f"{c} {v:.2g}" for c, v in zip(CHANNELS, p, strict=True))
    )
    return lines + ([f"WARNING: {w}" for w in warnings] or ["no warnings: the fit looks sound"])


def _classical_dict(fit) -> dict | None:
    if fit is None:
        return None
    names = ("mass", "damping", "stiffness", "mass_se", "damping_se", "stiffness_se", "vaf_overall", "dof")
    return {k: np.asarray(getattr(fit, k)) for k in names}


@functools.cache
def _simulate_jit():
    return jax.jit(simulate, static_argnames="numerics")


def model_outputs(res, f, numerics) -> tuple[np.ndarray, np.ndarray]:
    """The noise-free simulation of the fitted model (ideal sensors, no voluntary force)
    under ``f``: hand position [m] and force [N], ``(N, 2)`` each."""
    clean = dataclasses.replace(res.trial, sensors=Sensors(), voluntary=None)
    sim = _simulate_jit()(clean, np.asarray(f), numerics=numerics)
    return np.asarray(sim.x), np.asarray(sim.fh)


def welch_estimate(rec: dict, fs: float):
    """The Welch estimate of ``Z`` that ``identify``'s classical answer was fitted to (segments of
    the largest power of two up to 8192 that gives two, 75% overlap, up to 15 Hz)."""
    n = rec["x"].shape[0]
    nperseg = min(8192, 2 ** int(math.floor(math.log2(n / 2))))
    run_ = functools.partial(estimate, fs=fs, nperseg=nperseg, noverlap=3 * nperseg // 4)
    return jax.jit(run_)(rec["f_delta"], rec["x"], rec["fh"])


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
    n = x.shape[0]
    nperseg = min(4096, 2 ** int(math.floor(math.log2(max(n / 4, 16)))))
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


def frf_figure(f, z_measured, f_model, z_model, z_classical=None):
    """(c) ``|Z_ij|`` [N/m] of the identified arm's ``-M w^2 + j w B + K`` (and of the classical
    fit) at ``f_model`` [Hz] over the Welch estimate at ``f``."""
    fig = Figure(figsize=(15, 4), layout="constrained")
    axes = fig.subplots(1, 4, sharex=True)
    for ax, (i, j) in zip(axes, ELEMENTS):
        ax.loglog(f, np.abs(z_measured[:, i, j]), ".-", ms=3, lw=0.8, label="Welch estimate")
        ax.loglog(f_model, np.abs(z_model[:, i, j]), "k-", lw=1.2, label="identified model")
        if z_classical is not None:
            ax.loglog(f_model, np.abs(z_classical[:, i, j]), "--", lw=1, label="classical fit")
        ax.set_title(f"$|Z_{{{'xy'[i]}{'xy'[j]}}}|$", fontsize=10)
        ax.set_xlabel("frequency [Hz]")
        ax.xaxis.set_minor_formatter(NullFormatter())  # no crowded minor labels on short bands
        ax.yaxis.set_minor_formatter(NullFormatter())
    axes[0].set_ylabel("magnitude [N/m]")
    axes[0].legend(fontsize=8)
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


def model_settings(trial) -> dict:
    """Every value of a ``Trial`` as plain JSON values, with the controller's type."""
    return {"controller_type": type(trial.controller).__name__, **to_jsonable(trial)}


def result_dict(res, *, model, settings: dict, n_samples: int, warnings: list[str]) -> dict:
    """What ``identification.json`` holds (before strict JSON conversion)."""
    parameters = {}
    for e in entries(res):
        entry = parameters.setdefault(e.parameter, dict(unit=e.unit, entries={}))
        entry["entries"][e.index] = {k: getattr(e, k) for k in Entry._fields[4:]}
    for name, entry in parameters.items():
        entry.update(value=res.values[name], se=res.se[name])
    return {
        "settings": {**settings, "armimp_jax": package_version()},
        "record": {"n_samples": n_samples, "duration_s": n_samples / float(settings["fs_hz"])},
        "convention": (
            "arm matrices indexed [output, input] (row: force axis, column: displacement axis) in the "
            "recording's frame; friction per joint; a 95% interval is value +- 1.96 se (normal); se and "
            "covariance by indirect inference over the model's noise draws; statistics: the recording's own "
            "statistics that identify matched, by label (the classical fit for the arm, the friction "
            "regression's coefficients and log RMS speed per joint) (docs/identification.md)"
        ),
        "statistics": res.statistics,
        "converged": res.converged,
        "message": res.message,
        "intervals_reliable": res.intervals_reliable,
        "cost": res.cost,
        "iterations": res.iterations,
        "history": res.history,
        "draws": res.draws,
        "time_s": res.time_s,
        "parameters": parameters,
        "labels": list(res.labels),
        "covariance": np.asarray(res.covariance),
        "vaf": {"position": np.asarray(res.vaf_position), "force": np.asarray(res.vaf_force)},
        "whiteness_p": dict(zip(CHANNELS, np.asarray(res.whiteness_p).tolist(), strict=True)),
        "classical": _classical_dict(res.classical),
        "start_model": model_settings(model),
        "fitted_model": model_settings(res.trial),
        "warnings": list(warnings),
    }


def write_results(
    out_dir, res, rec: dict, *, model, settings: dict, numerics, warnings: list[str]
) -> list[pathlib.Path]:
    """Write ``identification.json`` (strict JSON: ``settings`` with the package version, the
    estimates, SEs, 95% intervals, covariance, fit quality, the classical answer, the start
    and fitted models, ``warnings``), ``identification.csv`` (one row per entry) and
    ``position.png``, ``residual_spectrum.png``, ``frf.png``, ``stiffness_ellipse.png`` under
    ``out_dir``, each atomically; returns their paths. ``settings`` must hold ``fs_hz``."""
    out_dir = pathlib.Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    fs = float(settings["fs_hz"])
    x, fh = np.asarray(rec["x"]), np.asarray(rec["fh"])
    x_model, fh_model = model_outputs(res, rec["f_delta"], numerics)
    est = welch_estimate(rec, fs)
    arm = _arm_matrices(res)
    f_grid = np.geomspace(float(est.f[0]), float(est.f[-1]), 200)  # the models on a fine grid
    s = 2j * np.pi * f_grid[:, None, None]
    z_model = arm["arm.mass"] * s**2 + arm["arm.damping"] * s + arm["arm.stiffness"]
    c = res.classical
    json_path = out_dir / "identification.json"
    atomic_write_json(
        json_path, result_dict(res, model=model, settings=settings, n_samples=x.shape[0], warnings=warnings)
    )
    columns = Entry._fields
    frame = table([e._asdict() for e in entries(res)], {k: "string" for k in columns[:4]}, columns=columns)
    paths = [json_path, *write_table(frame, out_dir / "identification.csv")]
    figures = {
        "position.png": position_figure(
            np.arange(x.shape[0]) / fs, x, x_model, np.asarray(res.trial.x0), res.vaf_position
        ),
        "residual_spectrum.png": residual_figure(fs, x, fh, x_model, fh_model),
        "frf.png": frf_figure(
            np.asarray(est.f),
            np.asarray(est.Z),
            f_grid,
            z_model,
            None if c is None else np.asarray(c.impedance(f_grid)),
        ),
        "stiffness_ellipse.png": ellipse_figure(
            arm["arm.stiffness"], stiffness_draws(res), None if c is None else np.asarray(c.stiffness)
        ),
    }
    return paths + [save_figure(fig, out_dir / name) for name, fig in figures.items()]
