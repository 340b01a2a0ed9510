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

from .points import Point


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
