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
- ``run(rec, model, options)``: ``identify`` on a loaded recording (``study.recording.recording``).
- ``trust_warnings``, ``pooled_warnings``, ``entries``: where the fit cannot be trusted (per
  recording: ``recording_warnings``); every estimated number beside the classical answer (the
  Welch route at its defaults, ``estimate_recording.analyse``).
- ``write_results``: ``identification.json`` (strict), ``identification.csv`` and four figures
  (drawn by ``study.recording.recording_figures``; the printed text is ``study.recording.recording_report``'s).

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

from ..._estimation.diagnose import implausible
from ..._identification.identify import identify
from ..._identification.indirect import IDENTIFY_NUMERICS
from ..._identification.layout import ARM_PARAMETERS, parameter_units
from ..._model.sensors import Sensors
from ..._simulate import simulate
from ..._solver.numerics import METHODS, Numerics, named_solver
from ..runs.results import atomic_write_json, package_version, to_jsonable
from ..schema.config import REQUIRED, TRIAL_SECTIONS, ConfigError, build_trial, read_config
from ..sweep.figures import save_figure
from ..sweep.tables import table, write_table
from . import calibration_files
from .estimate_recording import analyse, route_settings, settings_record
from .identify_pool import SECTION as RECORDINGS_SECTION
from .recording import RecordingError
from .recording_figures import ellipse_figure, frf_figure, position_figure, residual_figure, stiffness_draws

SECTIONS = {
    **TRIAL_SECTIONS,
    "identify": {
        "free": ("names", parameter_units, REQUIRED),
        "symmetric": ("names", tuple(ARM_PARAMETERS), []),
        "draws": ("int", 8, 64),
        "jacobian_draws": ("int", 1, 8),
        "max_steps": ("int", 1, 20),
        "seed": ("int", 0, 0),
        "method": ("text", METHODS, IDENTIFY_NUMERICS.method),  # identify's default numerics
        "substeps": ("int", 1, IDENTIFY_NUMERICS.substeps),
    },
    "recordings": RECORDINGS_SECTION,  # several recordings in one identification (study.recording.identify_pool)
    "calibration": calibration_files.SECTION,  # the robot alone and known loads, calibrated first
}
REQUIRED_SECTIONS = ("controller", "arm", "friction", "identify")
CHANNELS = ("x", "y", "fh_x", "fh_y")  # identify's whiteness_p order: x1, x2, fh1, fh2
WHITENESS_P = 1e-3  # a Ljung-Box p-value below this: coloured residuals
VAF_MIN = 90.0  # [%] a channel the model explains less of: a poor fit
START_OFFSET = 1e-3  # [m] the recording's first position this far from [arm] endpoint: warn


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
    calibration_files.check(config, path)
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


def check_sensitivity(model, free, section: str = "[identify]") -> None:
    """One-line errors, before the fit or the design, for a ``--sensitivity`` the model cannot
    give: no free arm matrix (``section`` names where ``free`` is set), or no noise in the
    config (no SE to weigh the moves by)."""
    if not any(n in ARM_PARAMETERS for n in free):
        raise ValueError(f"--sensitivity needs the arm free ({section} free names arm.mass, ...)")
    if not model.noisy:
        raise ValueError("--sensitivity needs the config's noise ([sensors], [voluntary]): no SE to weigh by")


SENSITIVITY_HEAD = (
    "how well must you know your robot: each arm diagonal's move per 1% error in the robot (the force "
    "delay's per ms) [SE]"
)


def sensitivity_lines(trial, f, free, percent: float, **options) -> list[str]:
    """``robot_sensitivity`` of ``trial`` under ``f`` for the arm's matrices in ``free`` and the
    robot parameters ``free`` does not estimate, as lines: the table of each arm diagonal's move
    per 1% error in each (per ms of force delay) [SE], then a warning per parameter a ``percent``
    error (1 ms of delay) would move an entry by more than one SE. ``options``: the sampling
    (``numerics``, ``draws``, ``jacobian_draws``)."""
    from ..._design.sensitivity import robot_names, robot_sensitivity

    robot = [n for n in robot_names(trial) if n not in free]  # a free one is estimated
    if not robot:
        return ["every robot parameter with a value was estimated"]
    arm = tuple(n for n in free if n in ARM_PARAMETERS)
    sens = robot_sensitivity(trial, f, free=arm, robot=robot, plausible=percent, **options)
    return [sens.table(), *(f"warning: {w}" for w in sens.warnings)]


def sensitivity_report(res, rec: dict, options: dict, percent: float) -> list[str]:
    """How well must the lab know its robot for this answer: ``sensitivity_lines`` at the
    identified trial and the recording's perturbation (the draws and numerics of ``options``),
    under ``SENSITIVITY_HEAD``. A one-line ``ValueError`` where the arm is not free."""
    check_sensitivity(res.trial, options["free"])
    sampling = dict(
        numerics=options.get("numerics"),
        draws=options.get("draws", 64),
        jacobian_draws=options.get("jacobian_draws", 8),
    )
    return [SENSITIVITY_HEAD, *sensitivity_lines(res.trial, rec["f_delta"], options["free"], percent, **sampling)]


def trust_warnings(res, rec: dict, classical=None) -> list[str]:
    """Where the fit of ``res`` (an ``Identification``) cannot be trusted, one line each:
    convergence, ``identify``'s own warnings, then ``recording_warnings`` of its recording
    (``classical``: ``classical_fit``'s answer for it, or ``None``)."""
    return _search_warnings(res) + recording_warnings(res, rec["x"], classical)


def pooled_warnings(res, names, loaded, classical) -> list[str]:
    """``trust_warnings`` of a pooled ``Identification``: convergence and ``identify``'s own
    warnings once, then each recording's ``recording_warnings``, prefixed with its name
    (``names``: one per recording; ``loaded``: ``(group, rec)`` each; ``classical``: each
    recording's ``classical_fit``)."""
    out = _search_warnings(res)
    for name, fit, (group, rec), cls in zip(names, res.recordings, loaded, classical, strict=True):
        out += [f"recording {name} (group {group}): {w}" for w in recording_warnings(fit, rec["x"], cls)]
    return out


def _search_warnings(res) -> list[str]:
    out = []
    if not res.converged:
        out.append(f"the fit did not converge ({res.message}): its values and SEs cannot be trusted")
    return out + list(res.warnings)  # identify's own (identifiability, a model without noise, plausibility)


def recording_warnings(fit, x, classical=None) -> list[str]:
    """Where one recording's share of a fit cannot be trusted, one line each: ``fit`` (a
    ``RecordingFit``, or an ``Identification``: its first recording's) with residuals that are
    not white, a channel the model explains little of, a start away from the model's rest; and
    the classical answer beside it (``classical_fit``'s, or ``None``) with M or K negative."""
    res, out = fit, []
    p = np.asarray(res.whiteness_p)
    low = [f"{c} (p = {v:.2g})" for c, v in zip(CHANNELS, p, strict=True) if v < WHITENESS_P]  # NaN: no variance
    if low:
        out.append(
            f"the residuals are not white: {', '.join(low)} (Ljung-Box, p < {WHITENESS_P:g}); the model "
            "leaves structure in the recording (the person's own force, unmodelled dynamics or a wrong "
            "noise model), so read the SEs as approximate"
        )
    vaf = np.concatenate([res.vaf_position, res.vaf_force])
    poor = [f"{c} {v:.1f} %" for c, v in zip(CHANNELS, vaf, strict=True) if v < VAF_MIN]  # NaN: the robot alone
    if poor and getattr(res.trial, "voluntary", None) is not None:
        out.append(
            f"the model accounts for little of {', '.join(poor)} (VAF below {VAF_MIN:g} %): the person's own "
            "force ([voluntary]), which no model of the perturbation's response explains, is much of it; if "
            "the whiteness and the intervals hold, the fit is sound (else check the config and the frame)"
        )
    elif poor:
        out.append(
            f"the model accounts for little of {', '.join(poor)} (VAF below {VAF_MIN:g} %): a poor fit; "
            "check the config (robot, controller gains, acquisition) and the recording's frame and signs"
        )
    offset = float(np.linalg.norm(np.asarray(x)[0] - np.asarray(res.trial.x0)))
    if offset > START_OFFSET:
        out.append(
            f"the recording starts {1e3 * offset:.1f} mm from [arm] endpoint, where the model starts at rest: "
            "the recording's positions must be in the model's world frame (origin at the shoulder)"
        )
    return out + ([] if classical is None else [f"the classical fit: {w}" for w in implausible(classical[1])])


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


def entries(res, classical=None) -> list[Entry]:
    """Every entry of an ``Identification``, in the order of ``res.labels``, with the arm's beside
    the ``classical`` fit's (an ``ImpedanceFit``; ``None``: no classical column)."""
    out, units = [], parameter_units()
    for name, value in res.values.items():
        value, se = np.asarray(value), np.asarray(res.se[name])
        low, high = (np.asarray(a) for a in res.interval(name))
        field, cls = name.split(".")[1], classical if name in ARM_PARAMETERS else None
        cval = None if cls is None else np.asarray(getattr(cls, field))
        cse = None if cls is None else np.asarray(getattr(cls, field + "_se"))
        for idx in np.ndindex(value.shape):
            index = ",".join(map(str, idx))
            numbers = [float(a[idx]) for a in (value, se, low, high)]
            beside = [None if a is None else float(a[idx]) for a in (cval, cse)]
            out.append(Entry(name, index, f"{name}[{index}]", units[name], *numbers, *beside))
    return out


def classical_fit(rec: dict, fs: float):
    """The Welch route's answer for a loaded recording sampled at ``fs`` [Hz], at that route's
    defaults (``estimate_recording.analyse``: segments that follow the record, a fitted force-channel
    delay, spectral SEs): ``(Estimate, ImpedanceFit)``, or ``None`` for a record Welch cannot
    use. The model route prints and saves it beside its own answer."""
    try:
        return analyse(rec, fs=fs)
    except ValueError:
        return None


def _classical_dict(classical, n_samples: int, fs: float) -> dict | None:
    if classical is None:
        return None
    fit = classical[1]
    welch, fit_settings, _ = route_settings(n_samples, fs=fs)
    names = ("mass", "damping", "stiffness", "mass_se", "damping_se", "stiffness_se", "delay", "delay_se")
    return {
        "settings": settings_record(welch, fit_settings),
        **{k: np.asarray(getattr(fit, k)) for k in (*names, "vaf_overall", "dof")},
    }


@functools.cache
def _simulate_jit():
    return jax.jit(simulate, static_argnames="numerics")


def model_outputs(res, f, numerics) -> tuple[np.ndarray, np.ndarray]:
    """The noise-free simulation of the fitted model (ideal sensors, no voluntary force)
    under ``f``: hand position [m] and force [N], ``(N, 2)`` each."""
    clean = dataclasses.replace(res.trial, sensors=Sensors(), voluntary=None)
    sim = _simulate_jit()(clean, np.asarray(f), numerics=numerics)
    return np.asarray(sim.x), np.asarray(sim.fh)


def model_settings(trial) -> dict:
    """Every value of a ``Trial`` as plain JSON values, with the controller's type."""
    return {"controller_type": type(trial.controller).__name__, **to_jsonable(trial)}


def result_dict(res, *, model, settings: dict, n_samples: int, warnings: list[str], classical=None) -> dict:
    """What ``identification.json`` holds (before strict JSON conversion); ``classical``: what
    ``classical_fit`` gave, or ``None``."""
    fs = float(settings["fs_hz"])
    parameters = {}
    for e in entries(res, None if classical is None else classical[1]):
        entry = parameters.setdefault(e.parameter, dict(unit=e.unit, entries={}))
        entry["entries"][e.index] = {k: getattr(e, k) for k in Entry._fields[4:]}
    for name, entry in parameters.items():
        entry.update(value=res.values[name], se=res.se[name])
    return {
        "settings": {**settings, "armimp_jax": package_version()},
        "record": {"n_samples": n_samples, "duration_s": n_samples / fs},
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
        "classical": _classical_dict(classical, n_samples, fs),
        "start_model": model_settings(model),
        "fitted_model": model_settings(res.trial),
        "warnings": list(warnings),
        "spread_ratio": res.spread_ratio,
    }


def write_results(
    out_dir, res, rec: dict, *, model, settings: dict, numerics, warnings: list[str], classical=None
) -> list[pathlib.Path]:
    """Write ``identification.json`` (strict JSON: ``settings`` with the package version, the
    estimates, SEs, 95% intervals, covariance, fit quality, the ``classical`` answer (what
    ``classical_fit`` gave, or ``None``), the start and fitted models, ``warnings``),
    ``identification.csv`` (one row per entry) and ``position.png``, ``residual_spectrum.png``,
    ``frf.png``, ``stiffness_ellipse.png`` under ``out_dir``, each atomically; returns their
    paths. ``settings`` must hold ``fs_hz``."""
    out_dir = pathlib.Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    n_samples = np.asarray(rec["x"]).shape[0]
    json_path = out_dir / "identification.json"
    atomic_write_json(
        json_path,
        result_dict(res, model=model, settings=settings, n_samples=n_samples, warnings=warnings, classical=classical),
    )
    columns = Entry._fields
    rows = [e._asdict() for e in entries(res, None if classical is None else classical[1])]
    frame = table(rows, {k: "string" for k in columns[:4]}, columns=columns)
    paths = [json_path, *write_table(frame, out_dir / "identification.csv")]
    figures = _figures(res, rec, float(settings["fs_hz"]), numerics, classical)
    return paths + [save_figure(fig, out_dir / name) for name, fig in figures.items()]


def _figures(res, rec: dict, fs: float, numerics, classical) -> dict:
    """The four figures by file name: the recording beside the fitted model's noise-free
    simulation, and the identified arm beside the classical fit."""
    x, fh = np.asarray(rec["x"]), np.asarray(rec["fh"])
    x_model, fh_model = model_outputs(res, rec["f_delta"], numerics)
    est, fit = (None, None) if classical is None else classical
    band = (0.1, 15.0) if est is None else (float(est.f[0]), float(est.f[-1]))
    f_grid = np.geomspace(*band, 200)  # the models on a fine grid
    measured = None if est is None else (np.asarray(est.f), np.asarray(est.Z))
    return {
        "position.png": position_figure(
            np.arange(x.shape[0]) / fs, x, x_model, np.asarray(res.trial.x0), res.vaf_position
        ),
        "residual_spectrum.png": residual_figure(fs, x, fh, x_model, fh_model),
        "frf.png": frf_figure(
            f_grid,
            np.asarray(res.trial.arm.impedance(f_grid)),
            measured,
            None if fit is None else np.asarray(fit.impedance(f_grid)),
        ),
        "stiffness_ellipse.png": ellipse_figure(
            np.asarray(res.trial.arm.stiffness),
            stiffness_draws(res),
            None if fit is None else np.asarray(fit.stiffness),
        ),
    }
