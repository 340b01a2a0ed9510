"""How a run's points are read: a grid of value lists and/or a list of points (``expand``), from
a TOML file (``read_toml``) or ``--set NAME=V1,V2`` options (``parse_set``); each point a
``points.Point``."""

from __future__ import annotations

import itertools
import json
import pathlib
import tomllib
from collections.abc import Iterable, Mapping

import numpy as np

from .points import (
    KIND_SETTINGS,
    POINT_DEFAULTS,
    USER_ARM,
    Point,
    kind_takes,
    known_settings,
    setting_place,
    setting_sections,
)

# a point's settings whose one value is never a list (a kind's may be a per-joint pair or a matrix)
SCALAR_SETTINGS = tuple(k for k in POINT_DEFAULTS if k not in ("peak", "window", "arm"))


def expand(grid: Mapping[str, Iterable] | None = None, points: Iterable[Mapping] | None = None) -> list[Point]:
    """The points (``Point``) of a run: every entry of ``points`` (default one empty point)
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
    _check_kind_settings(grid, bases)
    out, seen = [], set()
    for base in bases:
        both = sorted(set(base) & set(grid))
        if both:
            raise ValueError(f"setting(s) {', '.join(both)} given both in a point and for every point")
        listed = sorted(k for k, v in base.items() if isinstance(v, list) and k in SCALAR_SETTINGS)
        if listed:
            raise ValueError(
                f"a point's values are not swept: {', '.join(listed)} in a point is a list; "
                "sweep it outside the points (a section, or --set)"
            )
        for combo in itertools.product(*grid.values()):
            point = Point.parse(base | dict(zip(grid, combo, strict=True)))
            key = json.dumps(point.settings, sort_keys=True)
            if key not in seen:
                seen.add(key)
                out.append(point)
    return out


def _check_kind_settings(grid: Mapping, bases: list) -> None:
    """Refuse a kind's setting that no kind the run names takes (a PD-only sweep given ``mhat``,
    LuGre given ``tau_s``): a point drops the settings of other kinds, so it would be ignored in
    silence. A kind not named for every point is its default too."""
    takes, named_kinds, known = set(POINT_DEFAULTS), {}, known_settings()
    for setting in KIND_SETTINGS:
        kinds = set(grid.get(setting, [])) | {b[setting] for b in bases if setting in b}
        if setting not in grid and any(setting not in b for b in bases):
            kinds.add(POINT_DEFAULTS[setting])
        if not all(isinstance(k, str) for k in kinds):
            return  # a kind that is no name: the point's own check says so
        named_kinds[setting] = sorted(kinds)
        takes |= {n for kind in kinds for n in kind_takes(setting, kind)}
    stray = sorted({k for k in [*grid, *(k for b in bases for k in b)] if k not in takes and k in known})
    if stray:
        kinds = "; ".join(f"{setting} {', '.join(k)}" for setting, k in named_kinds.items())
        raise ValueError(f"{', '.join(stray)}: not a setting of the kinds this run names ({kinds})")


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
        name = setting_name(name) if sep and name else name
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


RUN_OPTIONS = ("seeds", "base_seed", "method", "substeps")


def read_toml(path) -> tuple[dict, list | None, dict]:
    """``(grid, points, options)`` from a sweep's TOML file, in the trial configs' dialect
    (``study.schema.config``): a point's sections (``points.setting_sections``: ``[controller]``,
    ``[friction]``, ``[arm]``, ``[perturbation]``, ``[record]``, ``[sensors]``, ``[acquisition]``,
    ``[welch]``), in which a list is swept and a single value fixed; an optional ``[[points]]``
    array of tables of the same sections; an optional ``[run]`` table (``RUN_OPTIONS``). One-line
    errors; a file in the old flat ``[grid]`` dialect is refused, naming each setting's section."""
    path = pathlib.Path(path)
    try:
        data = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise ValueError(f"{path}: no such file") from None
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as err:
        raise ValueError(f"{path}: not valid TOML ({' '.join(str(err).split())})") from None
    if "grid" in data:
        raise ValueError(_old_dialect(path, data))
    run, points = data.pop("run", {}), data.pop("points", None)
    if not isinstance(run, dict):
        raise ValueError(f"{path}: [run] must be a table")
    bad = sorted(set(run) - set(RUN_OPTIONS))
    if bad:
        raise ValueError(f"{path}: unknown [run] option(s) {', '.join(bad)}; allowed: {', '.join(RUN_OPTIONS)}")
    if points is not None and not (isinstance(points, list) and all(isinstance(p, dict) for p in points)):
        raise ValueError(f"{path}: points must be an array of tables ([[points]])")
    grid = sectioned(data, str(path))
    points = (
        None if points is None else [sectioned(p, f"{path}: points[{i}]", point=True) for i, p in enumerate(points)]
    )
    return grid, points, run


def _old_dialect(path, data) -> str:
    """The one line refusing a file in the old flat dialect: each setting's section named."""
    flat = [data["grid"] if isinstance(data["grid"], dict) else {}]
    flat += [p for p in data.get("points", []) if isinstance(p, dict)]
    names = list(dict.fromkeys(name for table in flat for name in table))

    def place(name):
        if name == "arm" and any(isinstance(t.get("arm"), Mapping) for t in flat):
            return f"arm under [arm] location (or a user's {', '.join(USER_ARM)})"
        where = setting_place(name)
        return f"{name} (no such setting)" if where is None else f"{name} under [{where[0]}] {where[1]}"

    moves = "".join(f"; {place(name)}" for name in names)
    return f"{path}: [grid] is the old sweep dialect: name each setting in its section, as the trial configs do{moves}"


def sectioned(tables: Mapping, where: str, *, point: bool = False) -> dict:
    """The settings by name (a point's, or a grid's value lists) of a config's sections
    ``{section: {key: value}}`` (``points.setting_sections``); ``[arm]`` takes a ``location`` or
    a user's ``mass``, ``damping``, ``stiffness`` and ``endpoint``. One line naming the section
    and key otherwise (``point``: an entry of ``[[points]]``, whose sections are dotted keys)."""
    sections = setting_sections()
    out: dict = {}
    for section, table in tables.items():
        if not isinstance(table, Mapping):
            place = setting_place(section)  # a setting outside its section (the old flat dialect)
            hint = ""
            if place is not None:
                hint = "; write it as " + (f"{place[0]}.{place[1]} = ..." if point else f"[{place[0]}] {place[1]}")
            raise ValueError(f"{where}: {section} = {table!r} sits outside a section{hint}")
        if section not in sections:
            extra = "" if point else ", run, points"
            raise ValueError(f"{where}: unknown section [{section}]; allowed: {', '.join(sections)}{extra}")
        table = dict(table)
        if section in KIND_SETTINGS and "type" in table:  # an unknown kind first: its keys are unknown because it is
            for kind in table["type"] if isinstance(table["type"], list) else [table["type"]]:
                try:
                    KIND_SETTINGS[section][1](kind, where=section)
                except ValueError as err:
                    raise ValueError(f"{where}: {err}") from None
        if section == "arm" and set(USER_ARM) & set(table):
            if "location" in table:
                raise ValueError(f"{where}: [arm] takes a location or a user's {', '.join(USER_ARM)}, not both")
            out["arm"] = {k: table.pop(k) for k in USER_ARM if k in table}
        for key, value in table.items():
            if key not in sections[section]:
                allowed = ", ".join(sections[section]) + (f", {', '.join(USER_ARM)}" if section == "arm" else "")
                raise ValueError(f"{where}: unknown key {key!r} in [{section}]; allowed: {allowed}")
            out[sections[section][key]] = value
    return out


def setting_name(name: str) -> str:
    """A ``--set`` name: a point's setting (``tau_c``, a table column), or its config place
    ``section.key`` (``friction.tau_c``)."""
    section, dot, key = name.partition(".")
    if not dot:
        return name
    keys = setting_sections().get(section)
    if keys is None or key not in keys:
        raise ValueError(f"--set {name}: no such setting; name a setting (tau_c) or its section.key (friction.tau_c)")
    return keys[key]
