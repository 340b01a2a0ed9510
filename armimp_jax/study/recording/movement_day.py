"""A lab's day for a movement (``sweeps/movement.py``; docs/movement.md, "A lab's day"): the
TOML config read and checked, the ensemble (simulated from the config's reach, or the lab's own
files), the classical route (``estimate_ensemble``) and what it writes.

The day, step by step (``run_day``):

1. ``read_movement_config``: the config as plain values, every bad value one line
   (``ConfigError``) naming the file, the section and the key.
2. ``movement_trial``: the config's moving arm and trial (``[arm]``, ``[reach]``, ``[profile]``
   and the trial sections of ``study.schema.config``), when the day simulates.
3. ``plan_reaches``: the perturbation and the number of reaches, the config's (``[perturbation]``,
   ``[ensemble] repetitions``); with a ``[plan]`` section, ``reaches_needed``: the reaches its
   ``precision`` needs on each knot's diagonals (``aj.reaches_for``, the bound along the path).
4. ``gather``: the ensemble, simulated (``simulate_ensemble``) or read (``load_ensemble``).
5. ``estimate_ensemble`` at the config's knots, then ``write_day``: ``movement.csv`` (and
   ``movement.parquet`` with pyarrow), ``movement.json`` and the two figures
   (``study.recording.movement_figures``), each written atomically.
6. With ``[identify] route = "model"``: the model route too (``identify`` over the ensemble, the
   config's trial the model, through its friction where it has one), ``write_model``:
   ``movement_model.csv``, ``movement_model.json`` and the same two figures of its answer
   (``stiffness_ellipses_model.png``, ``impedance_time_model.png``).
"""

from __future__ import annotations

import pathlib
from typing import Any, NamedTuple

import jax
import numpy as np

from ... import presets
from ..._batch import simulate_ensemble
from ..._estimation.ensemble_fit import estimate_ensemble
from ..._identification.ensemble_identify import identify_ensemble, trial_values
from ..._model.arm import Arm
from ..._model.families import PaperNoise
from ..._model.friction import NO_FRICTION
from ..._model.movement import MinimumJerk, Profile
from ..runs.results import atomic_write_json, stamped
from ..schema.config import REQUIRED, TRIAL_SECTIONS, ConfigError, build_trial, read_config
from ..sweep.figures import save_figure
from ..sweep.tables import table, write_table
from .movement_figures import knot_view, path_figure, profile_figure
from .recording import load_ensemble, parse_columns

SECTIONS = {
    **{k: v for k, v in TRIAL_SECTIONS.items() if k != "arm"},
    "arm": {  # the still arm the reach starts from: a paper location, any key given overriding it
        "location": ("int", 1, None),
        "mass": ("matrix", "kg", None),
        "damping": ("matrix", "N s/m", None),
        "stiffness": ("matrix", "N/m", None),
        "endpoint": ("vector", "m", None),
    },
    "reach": {
        "displacement": ("vector", "m", REQUIRED),
        "onset": ("scalar", "s", REQUIRED),
        "duration": ("scalar", "s", REQUIRED),
        "record": ("scalar", "s", REQUIRED),
    },
    "profile": {
        "knots": ("numbers", "s", REQUIRED),
        "stiffness_scale": ("numbers", "times [arm] stiffness", None),
        "damping_scale": ("numbers", "times [arm] damping", None),
    },
    "perturbation": {"level": ("int", 1, None), "peak": ("pair", "N", None), "cutoff": ("scalar", "Hz", None)},
    "ensemble": {
        "repetitions": ("int", 2, 50),
        "seed": ("int", 0, 0),
        "files": ("texts", None, []),
        "columns": ("texts", None, []),  # ["fh_x=Fx", ...]: the files' names of the standard columns
        "period": ("scalar", "s", None),
    },
    "plan": {  # the reaches a precision needs, on the bound along the path (aj.reaches_for)
        "precision": ("scalar", "fraction of each value", None),
        "draws": ("int", 2, 8),  # perturbation draws behind the bound's expectation
    },
    "identify": {  # the model route too (aj.identify over the ensemble): "classical" runs the classical alone
        "route": ("text", ("classical", "model"), "classical"),
    },
    "estimate": {
        "window": ("scalar", "s", 0.1),
        "cutoff": ("scalar", "Hz", 30.0),
        "acquisition": ("text", ("instant", "plain"), "instant"),
    },
}
SIMULATED = ("arm", "reach", "controller", "perturbation")  # the sections a simulated day needs
LEVEL = 0.95
COLUMNS = ("parameter", "time", "entry", "value", "se", "low", "high", "truth", "unit")


class Plan(NamedTuple):
    """What the day records: the perturbation family and the number of reaches."""

    perturbation: Any
    repetitions: int


def read_movement_config(path) -> dict:
    """The config at ``path``, checked (module docstring); ``ConfigError`` (one line) otherwise."""
    config = read_config(path, SECTIONS, ("profile",))
    for section in ("ensemble", "estimate", "identify"):
        config.setdefault(section, {k: v[2] for k, v in SECTIONS[section].items()})
    knots, where = np.asarray(config["profile"]["knots"]), f"{path}: [profile]"
    if np.any(np.diff(knots) <= 0):
        raise ConfigError(f"{where} knots [s] must increase, got {knots.tolist()}")
    for key in ("stiffness_scale", "damping_scale"):
        scale = config["profile"][key]
        if scale is not None and (len(scale) != knots.size or min(scale) <= 0):
            raise ConfigError(f"{where} {key} needs one number > 0 per knot ({knots.size}), got {scale}")
    least = 4 * knots.size + 3  # estimate_ensemble's unknowns of one force axis, plus one
    if config["ensemble"]["repetitions"] < least:
        raise ConfigError(
            f"{path}: [ensemble] repetitions = {config['ensemble']['repetitions']} is fewer than the {least} the "
            f"classical route needs for {knots.size} knots (4 J + 3)"
        )
    try:
        parse_columns(",".join(config["ensemble"]["columns"]))
    except ValueError as err:
        raise ConfigError(f"{path}: [ensemble] columns: {err}") from None
    precision = config.get("plan", {}).get("precision")
    if precision is not None and not 0 < precision < 1:
        raise ConfigError(f"{path}: [plan] precision must lie in (0, 1) (a fraction of each value), got {precision}")
    for key in ("window", "cutoff"):
        if not config["estimate"][key] > 0:
            raise ConfigError(f"{path}: [estimate] {key} must be > 0, got {config['estimate'][key]}")
    if "perturbation" in config and (config["perturbation"]["level"] is None) == (
        config["perturbation"]["peak"] is None
    ):
        raise ConfigError(f"{path}: [perturbation] give level (the paper's, 1-3) or peak [N], not both nor neither")
    level = config.get("perturbation", {}).get("level")
    if level is not None and level not in presets.PERTURBATION_LEVELS:
        raise ConfigError(f"{path}: [perturbation] level must be one of the paper's 1-3, got {level}")
    if "reach" in config:
        r = config["reach"]
        if not (r["onset"] >= 0 and r["duration"] > 0 and r["onset"] + r["duration"] <= r["record"]):
            raise ConfigError(
                f"{path}: [reach] needs onset >= 0, duration > 0 and onset + duration <= record, got onset "
                f"{r['onset']:g} s, duration {r['duration']:g} s, record {r['record']:g} s"
            )
        if knots[0] < 0 or knots[-1] > r["record"]:
            raise ConfigError(
                f"{where} knots [s] must lie in the record (0 to {r['record']:g} s), got {knots.tolist()}"
            )
    return config


def _still_arm(config: dict, where: str) -> Arm:
    """``[arm]``: the paper's arm at ``location`` with the keys given in its place, or all four keys."""
    t = config["arm"]
    try:
        base = presets.arm(t["location"]) if t["location"] is not None else None
    except ValueError as err:
        raise ConfigError(f"{where}: [arm] {err}") from None
    names = ("mass", "damping", "stiffness", "endpoint")
    if base is None and any(t[n] is None for n in names):
        raise ConfigError(f"{where}: [arm] give location (the paper's arm, 1-4) or mass, damping, stiffness, endpoint")
    return Arm(*[np.asarray(getattr(base, n) if t[n] is None else t[n], dtype=float) for n in names])


def movement_trial(config: dict, *, where: str = "config"):
    """The config's trial: the still ``[arm]`` reaching ``[reach]`` displacement along a minimum-jerk
    path, ``K`` (and ``B``) scaled at the ``[profile]`` knots; no joint friction without a
    ``[friction]`` section. Needs float64."""
    missing = [s for s in SIMULATED if s not in config]
    if missing:
        raise ConfigError(f"{where}: missing section [{missing[0]}]; a simulated day needs {', '.join(SIMULATED)}")
    still, reach, profile = _still_arm(config, where), config["reach"], config["profile"]

    def along(key, matrix):
        scale = profile[key]
        return matrix if scale is None else Profile(profile["knots"], np.asarray(scale)[:, None, None] * matrix)

    try:
        start = np.asarray(still.endpoint)
        path = MinimumJerk(start, start + np.asarray(reach["displacement"]), reach["onset"], reach["duration"])
        arm = Arm(
            still.mass,
            along("damping_scale", np.asarray(still.damping)),
            along("stiffness_scale", np.asarray(still.stiffness)),
            path,
        )
    except ValueError as err:
        raise ConfigError(f"{where}: [profile] or [reach]: {err}") from None
    return build_trial(config, where=where, arm=arm, friction=None if "friction" in config else NO_FRICTION)


def plan_reaches(config: dict, trial) -> Plan:
    """The hook of the day: the perturbation and the number of reaches to record. Today the
    config's (``[perturbation]``, ``[ensemble] repetitions``); later the design of a movement
    experiment and the reaches its precision needs, from ``trial``."""
    p = config["perturbation"]
    peak = presets.perturbation_peak(p["level"]) if p["level"] is not None else p["peak"]
    family = PaperNoise(peak) if p["cutoff"] is None else PaperNoise(peak, p["cutoff"])
    return Plan(family, config["ensemble"]["repetitions"])


def reaches_needed(config: dict, trial, plan: Plan):
    """``[plan] precision``'s reaches on the bound along the path (``aj.reaches_for``, the config's
    perturbation drawn ``[plan] draws`` times), or ``None`` without a ``[plan]`` section."""
    from ..._identification.path import perturbation_draws
    from ..._identification.path_bound import reaches_for

    wanted = config.get("plan", {}).get("precision")
    if wanted is None:
        return None
    n, draws = int(round(config["reach"]["record"] / trial.period)), config["plan"]["draws"]
    key = jax.random.key(config["ensemble"]["seed"] + 7919)
    f = perturbation_draws(plan.perturbation, key, draws, n, trial.period)
    return reaches_for(trial, f, precision=wanted)


def gather(config: dict, config_path, *, trial=None, plan: Plan | None = None):
    """The day's ensemble: ``plan``'s reaches of ``trial`` simulated (seed ``[ensemble] seed``),
    or, without a trial, the lab's ``[ensemble] files`` (relative to the config's folder)."""
    e = config["ensemble"]
    if trial is None:
        base = pathlib.Path(config_path).parent
        columns = parse_columns(",".join(e["columns"])) or None
        return load_ensemble([base / f for f in e["files"]], columns=columns, period=e["period"])
    samples = int(round(config["reach"]["record"] / trial.period))
    return simulate_ensemble(
        trial, plan.perturbation, key=jax.random.key(e["seed"]), repetitions=plan.repetitions, samples=samples
    )


def truth(trial, knots) -> dict:
    """``{"mass": (2, 2), "damping": (J, 2, 2), "stiffness": (J, 2, 2)}``: the arm at ``knots`` [s]."""
    arms = [trial.arm.at(t) for t in knots]
    return dict(
        mass=np.asarray(trial.arm.mass),
        damping=np.stack([np.asarray(a.damping) for a in arms]),
        stiffness=np.stack([np.asarray(a.stiffness) for a in arms]),
    )


def table_rows(fit, true: dict | None = None) -> list[dict]:
    """``fit.table()``'s rows (95% intervals) with the simulated arm's value (``truth``: NaN when unknown)."""
    rows = fit.table(LEVEL).to_dict("records")
    names = dict(M="mass", B="damping", K="stiffness")
    knots = list(np.asarray(fit.knots))
    for row in rows:
        i, k = ("xy".index(c) for c in row["entry"])
        value = None if true is None else np.asarray(true[names[row["parameter"]]])
        if value is not None and value.ndim == 3:
            value = value[knots.index(row["time"])]
        row["truth"] = np.nan if value is None else float(value[i, k])
    return rows


def write_day(out, ens, fit, *, true=None, settings: dict) -> list[pathlib.Path]:
    """Write ``movement.csv`` (one row per entry, ``COLUMNS``), ``movement.json`` (the same rows,
    strict JSON, with the settings, the package version, the ensemble and the covariance) and
    ``stiffness_ellipses.png``, ``impedance_time.png`` under ``out``, each atomically."""
    out = pathlib.Path(out)
    try:
        out.mkdir(parents=True, exist_ok=True)
        rows = table_rows(fit, true)
        frame = table(rows, {k: "string" for k in ("parameter", "entry", "unit")}, columns=COLUMNS)
        paths = write_table(frame, out / "movement.csv")
        sound = ens.sound()
        doc = dict(
            settings=stamped(settings),
            ensemble=dict(
                repetitions=ens.repetitions, sound=sound.repetitions, samples=ens.samples, period_s=ens.period
            ),
            convention=(
                "matrices indexed [output, input] (row: force axis, column: displacement axis); M shared by every "
                f"knot (time null); low, high: the {100 * LEVEL:g}% interval (Student's t, dof), clustered by "
                "repetition; truth: the simulated arm's value (null for a lab's recordings); covariance: per force "
                "axis, of [M row, (B_j row, K_j row) per knot] (docs/movement.md)"
            ),
            knots_s=np.asarray(fit.knots),
            dof=fit.dof,
            window_s=fit.window,
            cutoff_hz=fit.cutoff,
            entries=rows,
            covariance=np.asarray(fit.covariance),
            warnings=list(fit.warnings),
        )
        atomic_write_json(out / "movement.json", doc)
        paths.append(out / "movement.json")
        paths += draw(out, sound, fit, true)
    except OSError as err:
        raise ValueError(f"cannot write to {out}: {err.strerror or err}") from None
    return paths


def model_rows(fit, trial=None) -> list[dict]:
    """The model route's table (``fit.table()``: every knot's entries, ``tau_c`` through friction) with
    the simulated ``trial``'s value (NaN for a lab's recordings)."""
    rows = fit.table(LEVEL).to_dict("records")
    true = [np.nan] * len(rows) if trial is None else trial_values(trial)
    return [dict(row, truth=float(t)) for row, t in zip(rows, true, strict=True)]


def write_model(out, fit, trial, settings: dict, *, ens=None) -> list[pathlib.Path]:
    """``movement_model.csv`` and ``movement_model.json`` (the rows, the covariance, the search's
    state and warnings, the settings) under ``out``, each atomically; then, given the (sound)
    ensemble ``ens``, the two figures of the model route's answer (``model_figures``)."""
    out = pathlib.Path(out)
    rows = model_rows(fit, trial)
    try:
        paths = write_table(table(rows, {"entry": "string"}), out / "movement_model.csv")
        doc = dict(
            settings=stamped(dict(settings, identify=fit.settings)),
            converged=fit.converged,
            message=fit.message,
            steps=fit.steps,
            noise_ratio=fit.noise_ratio,
            entries=rows,
            covariance=np.asarray(fit.covariance),
            warnings=list(fit.warnings),
        )
        atomic_write_json(out / "movement_model.json", doc)
        figures = [] if ens is None else model_figures(out, ens, fit, trial)
    except OSError as err:
        raise ValueError(f"cannot write to {out}: {err.strerror or err}") from None
    return [*paths, out / "movement_model.json", *figures]


def model_figures(out, ens, fit, trial=None) -> list[pathlib.Path]:
    """``stiffness_ellipses_model.png`` and ``impedance_time_model.png``: the model route's answer
    drawn as the classical route's (``movement_figures.knot_view``), with the simulated ``trial``'s
    arm dashed; none where the fit gave no intervals or its knots cannot be drawn together."""
    view = knot_view(fit) if fit.converged and np.all(np.isfinite(fit.covariance)) else None
    if view is None:
        return []
    return draw(out, ens, view, None if trial is None else truth(trial, view.knots), suffix="_model")


def draw(out, ens, fit, true=None, *, suffix: str = "") -> list[pathlib.Path]:
    """``stiffness_ellipses{suffix}.png`` and ``impedance_time{suffix}.png`` of ``fit`` under ``out``."""
    pairs = (("stiffness_ellipses", path_figure), ("impedance_time", profile_figure))
    return [save_figure(fig(ens, fit, true), pathlib.Path(out) / f"{name}{suffix}.png", dpi=150) for name, fig in pairs]


def run_day(config_path, out, *, simulate: bool = False, echo=print) -> tuple:
    """The day of ``config_path`` (module docstring), written to ``out``; ``simulate``: simulate the
    config's reach even where ``[ensemble] files`` are listed (a dry run). Says what it does
    through ``echo``; returns ``(ensemble, fit, paths)``."""
    config = read_movement_config(config_path)
    simulated = simulate or not config["ensemble"]["files"]
    model_route = config["identify"]["route"] == "model"
    planned = simulated or "plan" in config or model_route  # the planned reach: simulation, [plan], the model
    trial = movement_trial(config, where=str(config_path)) if planned else None
    plan = plan_reaches(config, trial) if planned else None
    reaches = reaches_needed(config, trial, plan) if planned else None
    if reaches is not None:
        echo(reaches.summary())
    if simulated:
        echo(f"simulating {plan.repetitions} reaches of {config_path} (seed {config['ensemble']['seed']}) ...")
    else:
        echo(f"reading {len(config['ensemble']['files'])} repetitions listed in {config_path} ...")
    ens = gather(config, config_path, trial=trial if simulated else None, plan=plan)
    knots = config["profile"]["knots"]
    fit = estimate_ensemble(ens, knots=knots, **config["estimate"])
    settings = dict(config_path=str(config_path), config=config, simulated=simulated)
    if reaches is not None:
        settings["reaches_for"] = dict(precision=reaches.precision, per_entry=reaches.per_entry, worst=reaches.worst)
    true = truth(trial, knots) if simulated else None
    paths = write_day(out, ens, fit, true=true, settings=settings)
    lost = ens.repetitions - ens.sound().repetitions
    echo("\n".join([fit.summary(LEVEL)] + ([f"{lost} diverged repetitions left out"] if lost else [])))
    if model_route:
        echo(f"the model route over {ens.sound().repetitions} reaches (a few minutes on 2 cores) ...")
        model_fit = identify_ensemble(trial, ens)
        paths += write_model(out, model_fit, trial if simulated else None, settings, ens=ens.sound())
        echo(model_fit.summary(LEVEL))
        if not any(p.name.endswith("_model.png") for p in paths):
            echo("the model route's answer is not drawn: it gave no intervals, or its K has no knots (or B others)")
    echo(f"wrote {', '.join(str(p) for p in paths)}")
    return ens, fit, paths
