"""TOML configs of the scripts that build a trial (the model route of a recording, experiment
design): sections of typed keys, read and checked into plain values, then the ``Trial``.

- ``read_config(path, sections, required)``: the TOML, read and checked (no simulation).
  Every unknown section or key, missing section or key, wrong type or shape and unknown
  name is a ``ConfigError`` (a ``ValueError``) with one line naming the file, the section,
  the key and what is allowed.
- ``trial_parts(config, where=...)``: the parameter values of the sections in
  ``TRIAL_SECTIONS``, built by their constructors, the only validators (their range
  checks come back as ``ConfigError`` naming the section); ``build_trial`` the ``Trial``, the
  one builder: a sweep's point (``study.Point``) is built through it, its kinds given.
- ``[controller]`` and ``[friction]`` name a kind (``type = "admittance"``, ``type =
  "coulomb_viscous"``; the friction's default is ``"lugre"``) and take that kind's own
  parameters, read from its class (``kind_section``): a kind of one's own, once its class is
  defined, needs no edit here.

A section's spec maps each key to ``(kind, unit or allowed values or minimum, default)``;
a default of ``None`` is the library's own (the constructor's default), ``REQUIRED`` means
the key must be given.
"""

from __future__ import annotations

import dataclasses
import pathlib
import tomllib

import numpy as np

from ..._model import kinds
from ..._model.arm import Arm
from ..._model.controllers import controller_kind
from ..._model.friction import friction_kind
from ..._model.robot import MIT_MANUS
from ..._model.sensors import SETTINGS as SENSOR_SETTINGS
from ..._model.sensors import Sensors
from ..._model.voluntary import VoluntaryForce
from ..._simulate import make_trial

REQUIRED = object()  # a key without a default
ROBOT_PRESETS = ("mit_manus",)
TRIAL_SECTIONS = {
    "robot": {
        "preset": ("text", ROBOT_PRESETS, "mit_manus"),
        "shoulder_link": ("scalar", "m", None),
        "elbow_link": ("scalar", "m", None),
        "inertia": ("triple", "kg m^2", None),
        "base": ("vector", "m", None),
    },
    "controller": {"type": ("kind", controller_kind, REQUIRED)},  # and the kind's own keys (kind_section)
    "acquisition": {"mode": ("text", ("instant", "interval_mean"), "instant")},
    "sensors": {name: (shape, unit, default) for name, (unit, shape, default) in SENSOR_SETTINGS.items()},
    "voluntary": {"std": ("pair", "N", REQUIRED), "cutoff": ("scalar", "Hz", REQUIRED)},
    "arm": {
        "mass": ("matrix", "kg", REQUIRED),
        "damping": ("matrix", "N s/m", REQUIRED),
        "stiffness": ("matrix", "N/m", REQUIRED),
        "endpoint": ("vector", "m", REQUIRED),
    },
    "friction": {"type": ("kind", friction_kind, "lugre")},  # and the kind's own keys (kind_section)
}
SHAPES = {"scalar": (), "pair": (2,), "vector": (2,), "triple": (3,), "matrix": (2, 2)}
SHAPE_WORDS = {
    "scalar": "a number",
    "pair": "a number or a list of 2 numbers",
    "vector": "a list of 2 numbers [x, y]",
    "triple": "a list of 3 numbers",
    "matrix": "a 2x2 array [[a, b], [c, d]]",
}


class ConfigError(ValueError):
    """A config that cannot be used (one line naming the key)."""


def kind_section(spec: dict, table: dict, where: str) -> dict:
    """A kind section's keys: ``type`` (whose spec is ``("kind", lookup, default)``), then the
    named kind's parameters as its class gives them (2x2 gains are ``"matrix"``, per-joint
    values ``"pair"``, text options their words; defaults the constructor's own)."""
    _, lookup, default = spec["type"]
    name = table.get("type", None if default is REQUIRED else default)
    if name is None:
        return spec
    try:
        cls = lookup(name, where=f"{where} type")
    except ValueError as err:
        raise ConfigError(str(err)) from None
    out = {"type": spec["type"]}
    for p in cls.parameters().values():
        kind = "text" if p.shape is None else ("matrix" if p.shape == (2, 2) else "pair")
        out[p.name] = (kind, p.unit, REQUIRED if p.default is kinds.REQUIRED else None)
    return out


def _numeric_leaves(v) -> bool:
    if isinstance(v, list):
        return all(_numeric_leaves(x) for x in v)
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _value(where: str, key: str, spec, v):
    kind, extra, _ = spec
    if kind == "kind":  # checked by kind_section
        return v
    if kind == "text":
        if not isinstance(v, str) or v not in extra:
            raise ConfigError(f"{where} {key} must be one of {', '.join(map(repr, extra))}, got {v!r}")
        return v
    if kind == "int":
        if isinstance(v, bool) or not isinstance(v, int) or v < extra:
            raise ConfigError(f"{where} {key} must be an integer >= {extra}, got {v!r}")
        return v
    if kind == "texts":
        v = [v] if isinstance(v, str) else v
        if not isinstance(v, list) or not all(isinstance(n, str) for n in v):
            raise ConfigError(f"{where} {key} must be a list of strings, got {v!r}")
        return list(v)
    if kind == "choices":  # a list of integers from ``extra``
        v = [v] if isinstance(v, int) and not isinstance(v, bool) else v
        if not isinstance(v, list) or not all(isinstance(n, int) and not isinstance(n, bool) for n in v):
            raise ConfigError(f"{where} {key} must be a list of integers, got {v!r}")
        bad = [n for n in v if n not in extra]
        if bad:
            raise ConfigError(f"{where} {key}: {bad[0]!r} is not one of {', '.join(map(str, extra))}")
        return list(v)
    if kind == "names":  # extra: the allowed names, or a function giving them
        extra = tuple(extra()) if callable(extra) else extra
        v = [v] if isinstance(v, str) else v
        if not isinstance(v, list) or not all(isinstance(n, str) for n in v):
            raise ConfigError(f"{where} {key} must be a list of parameter names, got {v!r}")
        bad = [n for n in v if n not in extra]
        if bad:
            raise ConfigError(f"{where} {key}: unknown parameter {bad[0]!r}; allowed: {', '.join(extra)}")
        if len(set(v)) != len(v):
            raise ConfigError(f"{where} {key} names a parameter twice: {v}")
        return list(v)
    if kind == "numbers":  # a non-empty list of numbers (or one number)
        v = [v] if _numeric_leaves(v) and not isinstance(v, list) else v
        if not isinstance(v, list) or not v or not _numeric_leaves(v) or any(isinstance(n, list) for n in v):
            raise ConfigError(f"{where} {key} [{extra}] must be a number or a list of numbers, got {v!r}")
        if not all(np.isfinite(n) for n in v):
            raise ConfigError(f"{where} {key} [{extra}] must be finite, got {v!r}")
        return [float(n) for n in v]
    try:
        a = np.asarray(v, dtype=float) if _numeric_leaves(v) else None
    except ValueError:  # a ragged list
        a = None
    shape = SHAPES[kind]
    if a is None or not (a.shape == shape or (kind == "pair" and a.shape == ())) or not np.all(np.isfinite(a)):
        raise ConfigError(f"{where} {key} [{extra}] must be {SHAPE_WORDS[kind]}, got {v!r}")
    return a.tolist()


def read_config(path, sections: dict, required: tuple) -> dict:
    """The config at ``path`` as plain values (lists for arrays), with the defaults of
    ``sections`` filled in (``None``: the library's default). Raises ``ConfigError`` with one
    line naming the file, the section and the key."""
    path = pathlib.Path(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such file") from None
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as err:
        raise ConfigError(f"{path}: not valid TOML ({' '.join(str(err).split())})") from None
    unknown = [s for s in data if s not in sections]
    if unknown:
        raise ConfigError(f"{path}: unknown section [{unknown[0]}]; allowed: {', '.join(sections)}")
    missing = [s for s in required if s not in data]
    if missing:
        raise ConfigError(
            f"{path}: missing section [{missing[0]}]; required: {', '.join(required)} "
            f"(optional: {', '.join(s for s in sections if s not in required)})"
        )
    config = {}
    for section, keys in sections.items():
        if section not in data:
            continue
        table, where = data[section], f"{path}: [{section}]"
        if not isinstance(table, dict):
            raise ConfigError(f"{where} must be a table of keys, got {table!r}")
        is_kind = keys.get("type", (None,))[0] == "kind"
        if is_kind:
            keys = kind_section(keys, table, where)
        allowed = tuple(keys)
        bad = [k for k in table if k not in allowed]
        if bad:
            kind = f" for type {table['type']!r}" if is_kind and "type" in table else ""
            raise ConfigError(f"{where} unknown key {bad[0]!r}{kind}; allowed: {', '.join(allowed)}")
        out = {}
        for key, spec in keys.items():
            if key in table:
                out[key] = _value(where, key, spec, table[key])
            elif spec[2] is REQUIRED:
                unit = f" [{spec[1]}]" if spec[0] in SHAPES else ""
                required = ", ".join(k for k, s in keys.items() if s[2] is REQUIRED)
                raise ConfigError(f"{where} missing key {key!r}{unit}; required: {required}")
            elif key in allowed:
                out[key] = spec[2]
        config[section] = out
    return config


def _given(table: dict, keys) -> dict:
    return {k: table[k] for k in keys if table.get(k) is not None}


def _kind(lookup, table: dict):
    """The value of a kind section: its class (``type``) built from the keys given."""
    values = {k: v for k, v in table.items() if v is not None}
    return lookup(values.pop("type"))(**values)


def trial_parts(config: dict, *, where: str | None = "config", arm=None, friction=None, controller=None) -> dict:
    """The parameter values of ``config``'s trial sections, built by their constructors (the
    only validators): ``controller``, ``robot``, ``sensors``, ``voluntary``, ``arm``,
    ``friction`` (``make_trial``'s keywords). ``arm`` (an ``Arm``), ``friction`` (a friction
    law) and ``controller`` stand in for their sections when given. A constructor's
    one-line error comes back as ``ConfigError``,
    prefixed with ``where`` and the section (``where=None``: the constructor's line alone)."""

    def make(section, build):
        try:
            return build(config.get(section, {}))
        except ValueError as err:
            raise ConfigError(str(err) if where is None else f"{where}: [{section}] {err}") from None

    def robot(t):
        overrides = _given(t, ("shoulder_link", "elbow_link", "inertia", "base"))
        return dataclasses.replace(MIT_MANUS, **overrides) if overrides else MIT_MANUS

    def control(t):
        return _kind(controller_kind, t)

    def sensors(t):
        return Sensors(**{name: t[name] for name in SENSOR_SETTINGS}) if t else Sensors()

    return dict(
        robot=make("robot", robot),
        controller=controller if controller is not None else make("controller", control),
        sensors=make("sensors", sensors),
        voluntary=make("voluntary", lambda t: VoluntaryForce(t["std"], t["cutoff"]) if t else None),
        arm=arm
        if arm is not None
        else make("arm", lambda t: Arm(t["mass"], t["damping"], t["stiffness"], t["endpoint"])),
        friction=friction
        if friction is not None
        else make("friction", lambda t: _kind(friction_kind, {"type": "lugre", **t})),
    )


def build_trial(config: dict, *, where: str | None = "config", arm=None, friction=None, controller=None):
    """The ``Trial`` of ``config``'s trial sections (``trial_parts``, then ``make_trial`` with
    the ``[acquisition]`` mode); ``arm`` (an ``Arm``), ``friction`` and ``controller`` in place
    of their sections when given. The one way a trial is built from settings: a sweep's point
    gives its own (``Point.trial``) through it. Needs float64."""
    flat = sorted(k for k, v in config.items() if not isinstance(v, dict))
    if flat:  # a sweep's flat point (controller = "pd", tau_c = 0.5) is no config of sections
        raise ConfigError(
            f"{where or 'build_trial'}: takes a trial's sections ({{'controller': {{'type': 'pd'}}, ...}}), got "
            f"flat key(s) {', '.join(map(repr, flat[:4]))}: a sweep point's trial is study.Point.parse(point).trial"
        )
    parts = trial_parts(config, where=where, arm=arm, friction=friction, controller=controller)
    acquisition = config.get("acquisition", {}).get("mode", "instant")
    ctrl = parts.pop("controller")
    try:
        return make_trial(ctrl, acquisition=acquisition, **parts)
    except ValueError as err:
        raise ConfigError(str(err) if where is None else f"{where}: [arm] {err}") from None
