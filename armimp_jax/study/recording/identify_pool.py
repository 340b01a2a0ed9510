"""The model route for several recordings (postures, repeated trials, the robot alone): an
identify config with a ``[recordings]`` section -> one pooled ``identify`` -> one table.

- ``SECTION``: the ``[recordings]`` keys (``files`` relative to the config; ``groups``, one per
  file, default each file its own; ``alone``: the groups recorded with nothing on the handle;
  ``shared``: ``identify``'s, default every name but the arm's).
- ``build_recordings(config, loaded, where)``: one ``aj.Recording`` per loaded file, its model
  the config's trial at the file's first hand position (each posture rests where its recording
  starts), with ``aj.presets.no_arm`` for the robot alone.
- ``rows(res)``: every estimated entry, per group for the arm and once for the shared robot.
- ``write_results``: ``identification.json`` (strict: settings and version, every entry, the
  joint covariance, each recording's fit quality and classical answer) and
  ``identification.csv``, atomically. What the script prints is ``study.recording.recording_report``'s.
"""

from __future__ import annotations

import pathlib

import numpy as np

from ..._identification.layout import parameter_units
from ..._identification.pool import Recording
from ..._model.arm import Arm, no_arm
from ..runs.results import atomic_write_json, package_version
from ..schema.config import ConfigError, build_trial
from ..sweep.tables import table, write_table

SECTION = {
    "files": ("texts", None, []),
    "groups": ("texts", None, []),
    "alone": ("texts", None, []),
    "shared": ("names", parameter_units, None),
}
COLUMNS = ("parameter", "group", "index", "label", "unit", "value", "se", "low95", "high95")


def files(config: dict, config_path) -> list[tuple[pathlib.Path, str]]:
    """``[(path, group), ...]`` of the ``[recordings]`` section (paths relative to the config).
    One-line ``ConfigError`` for no files, a group count that is not the file count, or an
    ``alone`` name that is no group."""
    section, where = config["recordings"], f"{config_path}: [recordings]"
    names = section["files"]
    if not names:
        raise ConfigError(f"{where} files must list at least one recording")
    groups = section["groups"] or [pathlib.Path(n).stem for n in names]
    if len(groups) != len(names):
        raise ConfigError(f"{where} groups must name one group per file: {len(names)} files, {len(groups)} groups")
    unknown = [g for g in section["alone"] if g not in groups]
    if unknown:
        raise ConfigError(f"{where} alone names {unknown[0]!r}, which is no group; groups: {', '.join(groups)}")
    base = pathlib.Path(config_path).parent
    return [(base / n, g) for n, g in zip(names, groups, strict=True)]


def build_recordings(config: dict, loaded, where: str) -> list[Recording]:
    """One ``Recording`` per ``(group, rec)`` of ``loaded`` (``study.recording.recording``'s dicts): the
    config's trial with its arm at the recording's first hand position (``aj.presets.no_arm`` there for
    an ``alone`` group). Needs float64."""
    alone, arm = set(config["recordings"]["alone"]), config["arm"]
    out = []
    for group, rec in loaded:
        rest = np.asarray(rec["x"])[0]
        start = no_arm(rest) if group in alone else Arm(arm["mass"], arm["damping"], arm["stiffness"], rest)
        model = build_trial(config, where=f"{where} (recording of group {group!r})", arm=start)
        out.append(Recording(model, rec["f_delta"], rec["x"], rec["fh"], group=group))
    return out


def rows(res) -> list[dict]:
    """Every entry of a pooled ``Identification``: its parameter, group (``""``: shared), index,
    label, unit, value, SE and 95% interval."""
    out, units = [], parameter_units()
    for name, value in res.values.items():
        base, _, group = name.partition("@")
        value, se = np.asarray(value), np.asarray(res.se[name])
        low, high = (np.asarray(a) for a in res.interval(name))
        for idx in np.ndindex(value.shape):
            index = ",".join(map(str, idx))
            numbers = dict(value=value[idx], se=se[idx], low95=low[idx], high95=high[idx])
            row = dict(parameter=base, group=group, index=index, label=f"{name}[{index}]", unit=units[base])
            out.append(row | {k: float(v) for k, v in numbers.items()})
    return out


CLASSICAL = ("mass", "mass_se", "damping", "damping_se", "stiffness", "stiffness_se", "delay", "vaf_overall")


def fits(res, classical=None) -> list[dict]:
    """Each recording's fit quality: its group, VAF per axis [%], whiteness p-values, stuck share,
    and with ``classical`` (one ``(Estimate, ImpedanceFit)`` or ``None`` per recording) the
    classical answer's ``CLASSICAL`` fields (``None`` for a record Welch cannot use)."""
    keys = ("vaf_position", "vaf_force", "whiteness_p", "stuck_fraction")
    out = [dict(group=r.group, **{k: np.asarray(getattr(r, k)) for k in keys}) for r in res.recordings]
    for row, cls in zip(out, classical or [], strict=False):
        row["classical"] = None if cls is None else {k: np.asarray(getattr(cls[1], k)) for k in CLASSICAL}
    return out


def write_results(out_dir, res, *, settings: dict, warnings: list[str], classical=None) -> list[pathlib.Path]:
    """``identification.json`` and ``identification.csv`` under ``out_dir``, each atomically;
    ``classical``: each recording's classical answer (``fits``), or ``None``."""
    out_dir = pathlib.Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    entries = rows(res)
    doc = {
        "settings": {**settings, "armimp_jax": package_version()},
        "convention": (
            "one identification of every recording: a parameter with a group is that group's (the arm at "
            "each posture), one without is shared (the robot, its friction, the force channel); a 95% "
            "interval is value +- 1.96 se; the covariance is joint, in the order of labels"
        ),
        "converged": res.converged,
        "message": res.message,
        "intervals_reliable": res.intervals_reliable,
        "iterations": res.iterations,
        "draws": res.draws,
        "time_s": res.time_s,
        "entries": entries,
        "labels": list(res.labels),
        "covariance": np.asarray(res.covariance),
        "recordings": fits(res, classical),
        "warnings": list(warnings),
    }
    json_path = out_dir / "identification.json"
    atomic_write_json(json_path, doc)
    frame = table(entries, {k: "string" for k in COLUMNS[:5]}, columns=COLUMNS)
    return [json_path, *write_table(frame, out_dir / "identification.csv")]
