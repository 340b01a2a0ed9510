"""The points of a sweep: every setting of one trial, its default and unit; the typed ``Point``.

A *point*'s settings are a flat dict of JSON values that fixes one trial apart from its seed: the
controller's kind and its gains, the friction law's kind and its parameters, the arm (paper
location 1-4 or a user's matrices), the perturbation (level or peak, record length), the
sensors, the acquisition and the Welch settings. The base settings are ``POINT_DEFAULTS``;
a kind's own settings come from its class (``point_parameters``: IMBIC's ``mhat``, PD's
``kp`` and ``kv``, LuGre's ``tau_c`` with the stiction as a ratio, an admittance's ``m_v``
...; a gain given as a number is that times the identity), so a kind of one's own sweeps
with no edit here. ``known_settings()`` lists them all. ``normalize_point`` resolves every
default into a number and drops the settings the point's kinds do not take (a PD point
ignores ``mhat``), so equal trials give equal points (and keys). ``Point`` is a point typed
from parse to table: its settings, and the parts built from them once (the kinds, the arm,
the ``Trial``, ``Welch``, its batch group and table columns). ``study.schema.grids`` reads a run's
points from grids, TOML and ``--set``.
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import json
import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from ..._checks import check_choice
from ..._estimation.welch import Welch
from ..._model.arm import Arm
from ..._model.controllers import CONTROLLER_KINDS, controller_kind
from ..._model.friction import FRICTION_KINDS, friction_kind
from ..._model.kinds import REQUIRED
from ..._model.sensors import SETTINGS as SENSOR_SETTINGS
from ..._model.sensors import static_settings as sensor_static
from ..._simulate import ACQUISITIONS, Trial
from ...presets import LOCATIONS, PERTURBATION_LEVELS, perturbation_peak
from ...presets import arm as paper_arm
from ..runs.results import settings_key
from . import config

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
# A config's sections (the one TOML dialect, shared with the trial configs of ``study.schema.config``):
# section -> {key: the point's setting}; ``[controller]`` and ``[friction]`` take ``type`` and the
# kinds' own settings (``setting_sections``), ``[arm]`` a location or a user's four matrices.
BASE_SECTIONS = {
    "arm": {"location": "arm"},
    "perturbation": {"level": "perturbation_level", "peak": "peak"},
    "record": {"seconds": "seconds"},
    "sensors": {name: name for name in SENSOR_SETTINGS},
    "acquisition": {"mode": "acquisition"},
    "welch": {name: name for name in ("nperseg", "noverlap", "fmax", "window", "nfft")},
}
USER_ARM = ("mass", "damping", "stiffness", "endpoint")  # [arm]'s keys of a user's arm


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


def kind_takes(setting: str, kind: str) -> dict:
    """Every point setting the ``kind`` chosen for ``setting`` takes: its settings and its text
    options (``kind_settings`` | ``kind_options``)."""
    return kind_settings(setting, kind) | kind_options(setting, kind)


def known_settings() -> dict:
    """``{name: (default, unit)}`` of every setting a point may name: ``POINT_DEFAULTS`` and the
    settings of every registered kind (a name two kinds share appears once, with the first's
    default)."""
    out = {k: (v, POINT_UNITS.get(k)) for k, v in POINT_DEFAULTS.items()}
    for setting, (registry, _) in KIND_SETTINGS.items():
        for kind in registry.names():
            for name, spec in kind_takes(setting, kind).items():
                out.setdefault(name, spec)
    return out


def setting_sections() -> dict:
    """``{section: {key: setting}}`` of every setting a point may name: ``BASE_SECTIONS``, and
    ``[controller]`` / ``[friction]`` with ``type`` and every registered kind's own settings."""
    out = {section: dict(keys) for section, keys in BASE_SECTIONS.items()}
    for setting, (registry, _) in KIND_SETTINGS.items():
        keys = {"type": setting}
        for kind in registry.names():
            keys |= {name: name for name in kind_takes(setting, kind)}
        out[setting] = keys
    return out


def setting_place(name: str) -> tuple[str, str] | None:
    """Where a config names a point setting, ``(section, key)``: ``("friction", "tau_c")``,
    ``("record", "seconds")``; ``None`` for a name no section takes."""
    for section, keys in setting_sections().items():
        for key, setting in keys.items():
            if setting == name:
                return section, key
    return None


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
        need = set(USER_ARM)
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
        if default is REQUIRED and name not in p:
            raise ValueError(f"{setting} {kind!r} needs {name}: it has no default")
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
    if isinstance(raw, Point):
        return dict(raw.settings)
    return dict(_normalized(raw)[0])


def _settings(raw: Mapping) -> dict:
    """A point's settings resolved to plain JSON values (``normalize_point``), before its parts
    are built."""
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
    return out


def _normalized(raw: Mapping) -> tuple[dict, dict, Welch]:
    """``normalize_point``'s point, with the trial's parts its constructors built (the checks)
    and its ``Welch``."""
    out = _settings(raw)
    controller, friction = point_parts(out)
    # the constructors check the values (the kinds built once, from the point's own values)
    parts = config.trial_parts(_sections(out), where=None, arm=point_arm(out), controller=controller, friction=friction)
    welch = point_welch(out)
    try:
        welch.check(n_samples(out))
    except ValueError as err:
        raise ValueError(f"seconds={out['seconds']:g}, nperseg={out['nperseg']}: {err}") from None
    return out, parts, welch


def _sections(point: Mapping) -> dict:
    """The trial sections a point's settings fill (its kinds and arm are given as built)."""
    return dict(acquisition=dict(mode=point["acquisition"]), sensors={k: point[k] for k in SENSOR_SETTINGS})


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


class Point(Mapping):
    """A sweep point, typed from parse to table: one trial apart from its seed (``Point.parse``).

    As a read-only mapping it is its settings (``normalize_point``'s plain JSON values: what a
    run saves and its trials' key hashes); its parts are built from them once, by their
    constructors: ``controller``, ``friction``, ``arm`` ..., the ``trial`` (on first use; needs
    float64), ``welch``, ``samples`` (record length at 1 kHz), ``group`` (what one compiled batch
    shares), ``columns`` (its table columns) and ``key`` (its trials' file stem)."""

    def __init__(self, settings: dict, parts: dict, welch: Welch):
        self._settings, self._parts, self.welch = settings, parts, welch

    @classmethod
    def parse(cls, raw: Mapping) -> Point:
        """The point of ``raw`` (settings by name; defaults filled in): ``ValueError`` (one line)
        as ``normalize_point``."""
        return raw if isinstance(raw, Point) else cls(*_normalized(raw))

    def __getitem__(self, name: str):
        return copy.deepcopy(self._settings[name])  # a list or table given out can't change the point

    def __iter__(self):
        return iter(self._settings)

    def __len__(self) -> int:
        return len(self._settings)

    def __hash__(self) -> int:
        return hash(self.key)

    def __repr__(self) -> str:
        return f"Point({self._settings!r})"

    @property
    def settings(self) -> dict:
        """A copy of its settings as a plain dict (what a record saves)."""
        return copy.deepcopy(self._settings)

    @property
    def controller(self):
        return self._parts["controller"]

    @property
    def friction(self):
        return self._parts["friction"]

    @property
    def arm(self) -> Arm:
        return self._parts["arm"]

    @property
    def sensors(self):
        return self._parts["sensors"]

    @functools.cached_property
    def trial(self) -> Trial:
        """Its ``Trial`` on MIT-MANUS (``config.build_trial`` of its parts; needs float64)."""
        kinds = dict(arm=self.arm, friction=self.friction, controller=self.controller)
        return config.build_trial(_sections(self._settings), where=None, **kinds)

    @functools.cached_property
    def samples(self) -> int:
        return n_samples(self._settings)

    @functools.cached_property
    def key(self) -> str:
        """A short hash of its settings, stable across runs (its trials' file stem)."""
        return settings_key(dict(point=dict(self._settings)))[:12]

    @functools.cached_property
    def group(self) -> tuple:
        """What must agree within one compiled batch: controller and friction kinds (and their
        text options), acquisition, the sensors' static settings, record length and Welch."""
        p = self._settings
        options = tuple((n, p[n]) for s in KIND_SETTINGS for n in kind_options(s, p[s]) if n in p)
        return (p["controller"], p["friction"], p["acquisition"], *sensor_static(p), self.samples, self.welch, *options)

    @functools.cached_property
    def columns(self) -> dict:
        """Its settings as flat table columns (``point_columns``)."""
        return point_columns(self._settings)

    @property
    def noisy(self) -> bool:
        """Whether its trials draw sensor noise (its ``Sensors``' force or rate noise is on)."""
        return self.sensors.force_on or self.sensors.velocity_on


def static_group(point: Mapping) -> tuple:
    """What must agree within one compiled batch (``Point.group``)."""
    return Point.parse(point).group


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
        if k == "stiction_ratio":  # per joint where tau_c is
            tau_s = np.multiply(point["tau_c"], point["stiction_ratio"])
            cols["tau_s"] = json.dumps(tau_s.tolist()) if np.ndim(tau_s) else float(tau_s)
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
