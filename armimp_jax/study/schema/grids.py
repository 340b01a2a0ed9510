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

from .points import KIND_SETTINGS, USER_ARM, Point, known_settings, setting_place, setting_sections


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
    out, seen = [], set()
    for base in bases:
        both = sorted(set(base) & set(grid))
        if both:
            raise ValueError(f"setting(s) {', '.join(both)} given both in a point and in the grid")
        for combo in itertools.product(*grid.values()):
            point = Point.parse(base | dict(zip(grid, combo, strict=True)))
            key = json.dumps(point.settings, sort_keys=True)
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
    (``study.config``): a point's sections (``points.setting_sections``: ``[controller]``,
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
        grid = data["grid"] if isinstance(data["grid"], dict) else {}
        moves = "".join(f"; {name} under {setting_place(name)}" for name in grid)
        raise ValueError(
            f"{path}: [grid] is the old sweep dialect: name each setting in its section, as the trial "
            f"configs do{moves} (docs/sweeps.md)"
        )
    run, points = data.pop("run", {}), data.pop("points", None)
    if not isinstance(run, dict):
        raise ValueError(f"{path}: [run] must be a table")
    bad = sorted(set(run) - set(RUN_OPTIONS))
    if bad:
        raise ValueError(f"{path}: unknown [run] option(s) {', '.join(bad)}; allowed: {', '.join(RUN_OPTIONS)}")
    if points is not None and not (isinstance(points, list) and all(isinstance(p, dict) for p in points)):
        raise ValueError(f"{path}: points must be an array of tables ([[points]])")
    grid = sectioned(data, str(path))
    points = None if points is None else [sectioned(p, f"{path}: points[{i}]") for i, p in enumerate(points)]
    return grid, points, run


def sectioned(tables: Mapping, where: str) -> dict:
    """The settings by name (a point's, or a grid's value lists) of a config's sections
    ``{section: {key: value}}`` (``points.setting_sections``); ``[arm]`` takes a ``location`` or
    a user's ``mass``, ``damping``, ``stiffness`` and ``endpoint``. One line naming the section
    and key otherwise."""
    sections = setting_sections()
    out: dict = {}
    for section, table in tables.items():
        if not isinstance(table, Mapping):
            known = section in known_settings()
            hint = f"; write it as {setting_place(section)}" if known else ""
            raise ValueError(f"{where}: {section} = {table!r} sits outside a section{hint}")
        if section not in sections:
            raise ValueError(f"{where}: unknown section [{section}]; allowed: {', '.join(sections)}, run, points")
        table = dict(table)
        if section in KIND_SETTINGS and "type" in table:  # an unknown kind first: its keys are unknown because it is
            for kind in table["type"] if isinstance(table["type"], list) else [table["type"]]:
                KIND_SETTINGS[section][1](kind, where=section)
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
