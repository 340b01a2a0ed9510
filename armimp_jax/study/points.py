"""The points of a sweep: every setting of one trial, its default and unit, and how grids are read.

A *point* is a flat dict of JSON values that fixes one trial apart from its seed: the
controller's kind and its gains, the friction law's kind and its parameters, the arm (paper
location 1-4 or a user's matrices), the perturbation (level or peak, record length), the
sensors, the acquisition and the Welch settings. The base settings are ``POINT_DEFAULTS``;
a kind's own settings come from its class (``point_parameters``: IMBIC's ``mhat``, PD's
``kp`` and ``kv``, LuGre's ``tau_c`` with the stiction as a ratio, an admittance's ``m_v``
...; a gain given as a number is that times the identity), so a kind of one's own sweeps
with no edit here. ``known_settings()`` lists them all. ``normalize_point`` resolves every
default into a number and drops the settings the point's kinds do not take (a PD point
ignores ``mhat``), so equal trials give equal points (and keys). ``expand`` turns a grid of
value lists and/or a list of points into the normalized, de-duplicated points of a run;
``read_toml`` and ``parse_set`` read them from a TOML file and ``--set NAME=V1,V2`` options.
``build_trial`` makes a point's ``Trial``; ``point_columns`` its table columns.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import math
import pathlib
import tomllib
from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np

from .._checks import check_choice
from .._estimation.welch import Welch
from .._model.arm import Arm
from .._model.controllers import CONTROLLER_KINDS, controller_kind
from .._model.friction import FRICTION_KINDS, friction_kind
from .._model.sensors import SETTINGS as SENSOR_SETTINGS
from .._model.sensors import static_settings as sensor_static
from .._simulate import ACQUISITIONS, Trial
from ..presets import LOCATIONS, PERTURBATION_LEVELS, perturbation_peak
from ..presets import arm as paper_arm
from . import config
from .results import settings_key

# The settings of every point, their defaults and units (the kinds' own settings follow each
# kind: ``kind_settings``). ``None`` defaults are resolved by ``normalize_point`` (the peak from
# the perturbation level, the overlap from the segment).
POINT_DEFAULTS: dict[str, Any] = dict(
    controller="pd",  # a controller kind: "pd" | "imbic" | "admittance" | one's own
    friction="lugre",  # a friction kind: "lugre" | "coulomb_viscous" | one's own
    arm=1,  # paper location 1-4, or {"mass", "damping", "stiffness": 2x2, "endpoint": (2,)}
    perturbation_level=1,  # paper level 1-3 (None when a peak is given)
    peak=None,  # per-axis peak |F_Delta| [N], (2,); default: the level's
    seconds=50.0,  # record length [s]
    # the sensors' settings (``_model.sensors.SETTINGS``): force_noise [N], encoder_counts
    # [counts/rev] (None: exact angles), velocity_noise [rad/s]
    **{name: default for name, (_, _, default) in SENSOR_SETTINGS.items()},
    acquisition="instant",  # "instant" | "interval_mean"
    nperseg=8192,  # Welch segment [samples]
    noverlap=None,  # Welch overlap [samples]; default 3/4 of nperseg
    fmax=15.0,  # highest frequency estimated [Hz]
    window="hann",  # a scipy.signal.get_window name (or [name, param])
    nfft=None,  # FFT length [samples]; None: nperseg
)

POINT_UNITS = dict(
    peak="N",
    seconds="s",
    **{name: unit for name, (unit, _, _) in SENSOR_SETTINGS.items()},
    nperseg="samples",
    noverlap="samples",
    fmax="Hz",
    nfft="samples",
)
KIND_SETTINGS = {"controller": (CONTROLLER_KINDS, controller_kind), "friction": (FRICTION_KINDS, friction_kind)}


def kind_settings(setting: str, kind: str) -> dict:
    """``{name: (default, unit)}`` of the point settings of the ``kind`` chosen for ``setting``
    (``"controller"`` or ``"friction"``), from its class."""
    return KIND_SETTINGS[setting][1](kind, where=setting).point_parameters()


def kind_options(setting: str, kind: str) -> dict:
    """``{name: (default, allowed words)}`` of the text options of that kind (IMBIC's
    ``accel_estimate``): a point names one only where it departs from its default, so a
    point that names none is the one it always was."""
    cls = KIND_SETTINGS[setting][1](kind, where=setting)
    return {
        p.name: (p.default, p.unit) for p in cls.parameters().values() if p.shape is None and isinstance(p.default, str)
    }


def known_settings() -> dict:
    """``{name: (default, unit)}`` of every setting a point may name: ``POINT_DEFAULTS`` and the
    settings of every registered kind (a name two kinds share appears once, with the first's
    default)."""
    out = {k: (v, POINT_UNITS.get(k)) for k, v in POINT_DEFAULTS.items()}
    for setting, (registry, _) in KIND_SETTINGS.items():
        for kind in registry.names():
            for name, spec in (kind_settings(setting, kind) | kind_options(setting, kind)).items():
                out.setdefault(name, spec)
    return out


def setting_unit(name: str) -> str | None:
    """The unit of a point setting (``None``: unitless or unknown)."""
    unit = known_settings().get(name, (None, None))[1]
    return unit if isinstance(unit, str) and unit != "-" else None


def _number(name: str, value, *, minimum: float | None = None, exclusive: bool = False, integer: bool = False):
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ValueError(f"{name} must be a finite number, got {value!r}")
    if integer and int(value) != value:
        raise ValueError(f"{name} must be an integer, got {value!r}")
    if minimum is not None and (value <= minimum if exclusive else value < minimum):
        raise ValueError(f"{name} must be {'>' if exclusive else '>='} {minimum:g}, got {value!r}")
    return int(value) if integer else float(value)


def _arm_setting(value):
    if isinstance(value, Mapping):
        need = {"mass", "damping", "stiffness", "endpoint"}
        if set(value) != need:
            raise ValueError(f"a user arm needs exactly the keys {', '.join(sorted(need))}; got {', '.join(value)}")
        arm = Arm(**{k: value[k] for k in need})  # the constructor checks shapes and values (one line)
        return {k: np.asarray(getattr(arm, k), dtype=float).tolist() for k in sorted(need)}
    if isinstance(value, bool) or value not in LOCATIONS:
        raise ValueError(
            f"arm must be a paper location ({', '.join(map(str, LOCATIONS))}) or a user arm, got {value!r}"
        )
    return int(value)


def _kind_value(name: str, value, default):
    """A kind's setting: a number, or (where the default is not a number: a per-joint pair, a
    matrix) a nested list of numbers of the default's shape."""
    if np.ndim(value) == 0:
        return _number(name, value)
    a = np.asarray(value, dtype=object)
    if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in a.ravel()):
        raise ValueError(f"{name} must be a number or a list of numbers, got {value!r}")
    if np.ndim(default) and a.shape != np.shape(default) and not (a.shape == (2,) or a.shape == (2, 2)):
        raise ValueError(f"{name} must be a number, a pair or a 2x2 list, got {value!r}")
    return np.asarray(value, dtype=float).tolist()


def _kind(setting: str, p: Mapping) -> dict:
    """``{setting: kind, its settings...}`` of a point, defaults filled in."""
    kind = p[setting]
    if not isinstance(kind, str):
        raise ValueError(f"{setting} must name a kind, got {kind!r}")
    out: dict[str, Any] = {setting: kind}
    for name, (default, _) in kind_settings(setting, kind).items():
        out[name] = _kind_value(name, p.get(name, default), default)
    for name, (default, words) in kind_options(setting, kind).items():
        if p.get(name, default) != default:
            check_choice(name, p[name], words)
            out[name] = p[name]
    return out


def normalize_point(raw: Mapping) -> dict:
    """The canonical form of a point: the base settings of ``POINT_DEFAULTS`` and the settings of
    its controller's and friction's kinds, resolved to plain JSON values (defaults filled in,
    numbers as floats, the peak from the perturbation level, the overlap from the segment);
    settings of other kinds are dropped.

    Raises ``ValueError`` (one line) for an unknown setting or kind, a value of the wrong type,
    or a value that cannot run: the parameter constructors (the kinds, ``Sensors``, ``Arm``;
    ``trial_parts``) and ``Welch``'s check are the validators, and their messages name the
    value and the allowed range."""
    for setting, (_, kind_of) in KIND_SETTINGS.items():
        if setting in raw:  # an unknown kind first: its settings are unknown because it is
            kind_of(raw[setting], where=setting)
    known = known_settings()
    unknown = [k for k in raw if k not in known]
    if unknown:
        raise ValueError(f"unknown setting(s) {', '.join(map(repr, unknown))}; known: {', '.join(known)}")
    p = dict(POINT_DEFAULTS) | dict(raw)
    out: dict[str, Any] = _kind("controller", p) | _kind("friction", p)
    out["arm"] = _arm_setting(p["arm"])
    out |= _perturbation(raw, p)
    out["seconds"] = _number("seconds", p["seconds"], minimum=0.0, exclusive=True)
    for name in SENSOR_SETTINGS:  # a setting whose default is None may stay None
        out[name] = None if p[name] is None and SENSOR_SETTINGS[name][2] is None else _number(name, p[name])
    check_choice("acquisition", p["acquisition"], ACQUISITIONS)
    out["acquisition"] = p["acquisition"]
    out |= _welch_settings(p)
    config.trial_parts(point_config(out), where=None, arm=point_arm(out))  # the constructors check the values
    try:
        point_welch(out).check(n_samples(out))
    except ValueError as err:
        raise ValueError(f"seconds={out['seconds']:g}, nperseg={out['nperseg']}: {err}") from None
    return out


def _perturbation(raw: Mapping, p: Mapping) -> dict:
    """``perturbation_level`` and ``peak`` of a point: a given peak (with a level only if it
    is that level's), or the level's peak."""
    if raw.get("peak") is None:
        level = p["perturbation_level"]
        if isinstance(level, bool) or level not in PERTURBATION_LEVELS:
            raise ValueError(
                f"perturbation_level must be one of {', '.join(map(str, PERTURBATION_LEVELS))}, got {level!r}"
            )
        return dict(perturbation_level=int(level), peak=perturbation_peak(int(level)).tolist())
    peak = p["peak"]
    peak = [peak, peak] if isinstance(peak, (int, float)) and not isinstance(peak, bool) else peak
    if not isinstance(peak, (list, tuple)) or len(peak) != 2:
        raise ValueError(f"peak must be a number or two numbers [N], got {p['peak']!r}")
    # perturbation() checks the peak too, but only once float64 is on: refuse it here already
    peak = [_number("peak [N]", v, minimum=0.0, exclusive=True) for v in peak]
    level = raw.get("perturbation_level")
    # a normalized point names both (level and its peak): accept that, refuse a mismatch
    if level is not None and (level not in PERTURBATION_LEVELS or perturbation_peak(level).tolist() != peak):
        raise ValueError(f"give perturbation_level or peak, not both (got level {level!r} and peak {p['peak']!r})")
    return dict(perturbation_level=level, peak=peak)


def _welch_settings(p: Mapping) -> dict:
    """The Welch settings of a point, typed (``Welch``'s check judges their values)."""
    out = dict(nperseg=_number("nperseg", p["nperseg"], integer=True))
    noverlap = 3 * out["nperseg"] // 4 if p["noverlap"] is None else p["noverlap"]
    out["noverlap"] = _number("noverlap", noverlap, integer=True)
    out["fmax"] = _number("fmax [Hz]", p["fmax"])
    window = p["window"]
    if not (isinstance(window, str) or (isinstance(window, (list, tuple)) and window and isinstance(window[0], str))):
        raise ValueError(f"window must be a name or [name, parameter, ...], got {window!r}")
    out["window"] = window if isinstance(window, str) else list(window)
    out["nfft"] = None if p["nfft"] is None else _number("nfft", p["nfft"], integer=True)
    return out


def n_samples(point: Mapping) -> int:
    """Record length of a point [samples at 1 kHz]."""
    return int(round(point["seconds"] * 1000))


def point_welch(point: Mapping) -> Welch:
    """The ``Welch`` settings of a normalized point (hashable: a window list becomes a tuple)."""
    window = point["window"] if isinstance(point["window"], str) else tuple(point["window"])
    return Welch(point["nperseg"], point["noverlap"], point["fmax"], window=window, nfft=point["nfft"])


def point_arm(point: Mapping) -> Arm:
    """The ``Arm`` of a normalized point: a paper location's, or the user's."""
    return paper_arm(point["arm"]) if isinstance(point["arm"], int) else Arm(**point["arm"])


def point_parts(point: Mapping) -> tuple:
    """``(controller, friction)`` of a normalized point, built by their kinds' ``from_point``."""
    out = []
    for setting in KIND_SETTINGS:
        kind = point[setting]
        values = {n: point[n] for n in kind_settings(setting, kind)}
        part = KIND_SETTINGS[setting][1](kind).from_point(values)
        options = {n: point[n] for n in kind_options(setting, kind) if n in point}
        out.append(dataclasses.replace(part, **options) if options else part)
    return tuple(out)


def point_config(point: Mapping) -> dict:
    """A normalized point as the trial sections of a TOML config (``study.config``): one
    schema, built by the same constructors (the arm is ``point_arm``'s; the controller and the
    friction as their records)."""
    controller, friction = point_parts(point)
    return dict(
        controller=controller.settings(),
        acquisition=dict(mode=point["acquisition"]),
        sensors={k: point[k] for k in SENSOR_SETTINGS},
        friction=friction.settings(),
    )


def build_trial(point: Mapping) -> Trial:
    """The ``Trial`` of a normalized point (``config.build_trial`` of ``point_config``, on
    MIT-MANUS). Needs float64."""
    return config.build_trial(point_config(point), where=None, arm=point_arm(point))


def static_group(point: Mapping) -> tuple:
    """What must agree within one compiled batch: controller and friction kinds (and their
    text options), acquisition, encoder on/off, record length and Welch settings."""
    options = tuple((n, point[n]) for s in KIND_SETTINGS for n in kind_options(s, point[s]) if n in point)
    return (
        point["controller"],
        point["friction"],
        point["acquisition"],
        *sensor_static(point),
        n_samples(point),
        point_welch(point),
        *options,
    )


def expand(grid: Mapping[str, Iterable] | None = None, points: Iterable[Mapping] | None = None) -> list[dict]:
    """The normalized points of a run: every entry of ``points`` (default one empty point)
    combined with the cartesian product of ``grid`` (setting -> list of values), de-duplicated
    in order (e.g. PD points that differ only in ``mhat``). A setting named both in a point
    and in the grid is refused."""
    grid = {k: list(v) if isinstance(v, (list, tuple)) else [v] for k, v in (grid or {}).items()}
    for name, values in grid.items():
        if not values:
            raise ValueError(f"grid setting {name!r} has no values")
    bases = [dict(p) for p in points] if points is not None else [{}]
    if not bases:
        raise ValueError("the list of points is empty")
    out, seen = [], set()
    for base in bases:
        both = sorted(set(base) & set(grid))
        if both:
            raise ValueError(f"setting(s) {', '.join(both)} given both in a point and in the grid")
        for combo in itertools.product(*grid.values()):
            point = normalize_point(base | dict(zip(grid, combo, strict=True)))
            key = json.dumps(point, sort_keys=True)
            if key not in seen:
                seen.add(key)
                out.append(point)
    return out


def _split_top(text: str) -> list[str]:
    parts, depth, start, quote = [], 0, 0, None
    for i, ch in enumerate(text):
        if quote:
            quote = None if ch == quote else quote
        elif ch in "\"'":
            quote = ch
        elif ch in "[{(":
            depth += 1
        elif ch in "]})":
            depth -= 1
        elif ch == "," and depth == 0:
            parts.append(text[start:i])
            start = i + 1
    parts.append(text[start:])
    return [p.strip() for p in parts]


def _value(text: str):
    if text in ("none", "None", "null"):
        return None
    try:
        return json.loads(text)
    except ValueError:
        return text  # a bare word: "pd", "hann", "interval_mean"


def parse_set(options: Iterable[str]) -> dict[str, list]:
    """Grid from ``--set`` options ``NAME=V1,V2,...``: values split at top-level commas, each
    read as JSON (``[3,3]``, ``{"mass": ...}``, ``null``/``none``) or else as a bare word.
    ``NAME=geom:A:B:N`` (N log-spaced values from A to B) and ``NAME=lin:A:B:N`` are ranges."""
    grid: dict[str, list] = {}
    for opt in options:
        name, sep, text = opt.partition("=")
        name = name.strip()
        if not sep or not name or not text.strip():
            raise ValueError(f"--set needs NAME=V1,V2,..., got {opt!r}")
        if name in grid:
            raise ValueError(f"--set {name} given twice")
        if text.startswith(("geom:", "lin:")):
            kind, *args = text.split(":")
            try:
                a, b, n = float(args[0]), float(args[1]), int(args[2])
            except (ValueError, IndexError):
                raise ValueError(f"--set {name}={text}: a range is {kind}:START:STOP:COUNT") from None
            if n < 1 or (kind == "geom" and not (a > 0 and b > 0)):
                raise ValueError(f"--set {name}={text}: need COUNT >= 1 (and START, STOP > 0 for geom)")
            grid[name] = (np.geomspace(a, b, n) if kind == "geom" else np.linspace(a, b, n)).tolist()
        else:
            grid[name] = [_value(v) for v in _split_top(text)]
    return grid


def read_toml(path) -> tuple[dict, list | None, dict]:
    """``(grid, points, options)`` from a TOML file: a ``[grid]`` table of settings (a list is
    swept, a single value fixed), an optional ``[[points]]`` array of tables, and an optional
    ``[run]`` table (``seeds``, ``base_seed``, ``method``, ``substeps``). One-line errors."""
    path = pathlib.Path(path)
    try:
        data = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise ValueError(f"{path}: no such file") from None
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as err:
        raise ValueError(f"{path}: not valid TOML ({' '.join(str(err).split())})") from None
    extra = sorted(set(data) - {"grid", "points", "run"})
    if extra:
        raise ValueError(f"{path}: unknown table(s) {', '.join(extra)}; allowed: grid, points, run")
    grid, points, run = data.get("grid", {}), data.get("points"), data.get("run", {})
    if not isinstance(grid, dict) or not isinstance(run, dict):
        raise ValueError(f"{path}: [grid] and [run] must be tables")
    if points is not None and not (isinstance(points, list) and all(isinstance(p, dict) for p in points)):
        raise ValueError(f"{path}: points must be an array of tables ([[points]])")
    bad = sorted(set(run) - {"seeds", "base_seed", "method", "substeps"})
    if bad:
        raise ValueError(
            f"{path}: unknown [run] option(s) {', '.join(bad)}; allowed: seeds, base_seed, method, substeps"
        )
    return grid, points, run


def point_columns(point: Mapping) -> dict:
    """The settings of a point as flat table columns (``arm`` a location or ``user-<hash>``;
    ``peak`` as ``peak_x``, ``peak_y`` [N]; LuGre's ``tau_s`` [N m] derived from the ratio; a
    kind's gain given as a matrix as JSON text)."""
    arm = point["arm"] if isinstance(point["arm"], int) else f"user-{settings_key(dict(arm=point['arm']))[:8]}"
    cols = {}
    for k, v in point.items():
        if k == "arm":
            cols["arm"] = arm
        elif k == "peak":
            cols["peak_x"], cols["peak_y"] = v
        elif k == "window":
            cols["window"] = v if isinstance(v, str) else ":".join(map(str, v))
        elif isinstance(v, list):
            cols[k] = json.dumps(v)
        else:
            cols[k] = v
        if k == "stiction_ratio":
            cols["tau_s"] = point["tau_c"] * point["stiction_ratio"]
    return cols


def swept_settings(points: list[Mapping]) -> list[str]:
    """The settings that take more than one value across ``points`` (``None``, a setting that
    does not apply, such as PD's ``mhat``, is not a value)."""
    names = list(dict.fromkeys(k for p in points for k in p))
    return [k for k in names if len({json.dumps(p[k]) for p in points if p.get(k) is not None}) > 1]


def is_numeric(points: list[Mapping], name: str) -> bool:
    """Whether setting ``name`` is a number wherever it applies (an axis to plot against)."""
    values = [p[name] for p in points if p.get(name) is not None]
    return (
        bool(values) and name != "arm" and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values)
    )


def default_x(points: list[Mapping]) -> str | None:
    """The first swept numeric setting of ``points`` (a summary figure's x axis), or ``None``."""
    numeric = [k for k in swept_settings(points) if is_numeric(points, k)]
    return numeric[0] if numeric else None
