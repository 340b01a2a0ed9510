"""The ``[calibration]`` section of the model route's config: the robot alone and the force
transducer against known loads, calibrated from the lab's files before the arm is identified
(``aj.calibrate_robot``, ``aj.calibrate_force``; docs/identify_recording.md), and handed to
``identify`` as its ``calibration``.

- ``SECTION``: the keys (``robot_files`` and ``load_files`` relative to the config, ``robot_force``,
  ``cutoff``, ``min_rate``).
- ``check(config, path)``: one line, before any file is read, for a section that calibrates
  nothing or a calibrated parameter also named in ``[identify] free``.
- ``calibrate(config, path, fs, columns, robot)``: the files read and checked (one line each, as
  ``study.recording.recording``'s), the calibrations, and the lines the script prints before the arm's.
- ``record(calibrations)``: every number of them for ``identification.json``.
"""

from __future__ import annotations

import math
import pathlib

import numpy as np

from ..._calibration.force_calibration import calibrate_force
from ..._calibration.robot_calibration import MIN_RATE, RobotRecording, calibrate_robot
from ..._identification.calibration_prior import ESTIMABLE
from ..schema.config import ConfigError
from .recording import load_recording

SECTION = {
    "robot_files": ("texts", None, []),
    "robot_force": ("text", ("recorded", "none"), "recorded"),
    "cutoff": ("scalar", "Hz", None),
    "min_rate": ("scalar", "rad/s", None),
    "load_files": ("texts", None, []),
}
# The columns of each kind of file (study.recording.recording's groups): the robot alone, its Cartesian
# command F_u [N] (the motors applying J^T F_u), hand position [m] and force reading [N]; the loads
# [N] and the transducer's readings under them [N], one row per reading
ROBOT_GROUPS = {"command": ("command_x", "command_y"), "x": ("x", "y"), "fh": ("fh_x", "fh_y")}
LOAD_GROUPS = {"load": ("load_x", "load_y"), "fh": ("fh_x", "fh_y")}
ROBOT_NAMES = ("robot.inertia", "friction.tau_c", "friction.viscous", "friction.sigma2")
FORCE_NAMES = ("sensors.force_gain", "sensors.force_offset")


def check(config: dict, path) -> None:
    """One-line ``ConfigError`` for a ``[calibration]`` with no files, a cut-off or ``min_rate``
    that is not positive, or a calibrated parameter that ``[identify] free`` also names (but the
    force offset, ``ESTIMABLE``: then estimated from the recording)."""
    section, where = config.get("calibration"), f"{path}: [calibration]"
    if section is None:
        return
    if not section["robot_files"] and not section["load_files"]:
        raise ConfigError(f"{where} calibrates nothing: give robot_files (the robot alone), load_files, or both")
    for key, unit in (("cutoff", "Hz"), ("min_rate", "rad/s")):
        value = section[key]
        if value is not None and not (math.isfinite(value) and value > 0):
            raise ConfigError(f"{where} {key} must be > 0 {unit}, got {value:g}")
    held = [*(ROBOT_NAMES if section["robot_files"] else ())]
    held += ["sensors.force_offset"] if section["robot_files"] and section["robot_force"] == "recorded" else []
    held += list(FORCE_NAMES) if section["load_files"] else []
    both = [n for n in config["identify"]["free"] if n in held and n not in ESTIMABLE]
    if both:
        raise ConfigError(
            f"{path}: [identify] free names {both[0]}, which [calibration] calibrates: it is held at the "
            "calibration's value and its uncertainty carried; leave it out of free"
        )


def _files(section: dict, key: str, path) -> list[pathlib.Path]:
    base = pathlib.Path(path).parent
    return [base / name for name in section[key]]


def _mapping(columns: dict, groups: dict) -> dict:
    """The command line's ``--columns`` entries that name a column of these files."""
    names = {c for pair in groups.values() for c in pair}
    return {k: v for k, v in columns.items() if k in names}


def robot_recordings(section: dict, path, fs: float, columns: dict) -> list[RobotRecording]:
    """The robot-alone files as ``RobotRecording``s (checked as they load)."""
    groups = dict(ROBOT_GROUPS)
    if section["robot_force"] == "none":
        del groups["fh"]
    out = []
    for file in _files(section, "robot_files", path):
        rec = load_recording(file, columns=_mapping(columns, groups), groups=groups)
        out.append(RobotRecording(x=rec["x"], command=rec["command"], fh=rec.get("fh"), period=1.0 / fs))
    return out


def load_readings(section: dict, path, columns: dict) -> tuple[np.ndarray, np.ndarray]:
    """``(loads (n, 2), readings (n, 2))``: every row of the load files, the readings averaged
    per distinct load (``calibrate_force`` averages per load too: the line's residuals, not the
    samples' spread, give its noise)."""
    rows = [
        load_recording(f, columns=_mapping(columns, LOAD_GROUPS), groups=LOAD_GROUPS)
        for f in _files(section, "load_files", path)
    ]
    loads = np.concatenate([r["load"] for r in rows])
    readings = np.concatenate([r["fh"] for r in rows])
    distinct, which = np.unique(loads, axis=0, return_inverse=True)
    which = np.ravel(which)
    means = np.stack([readings[which == i].mean(axis=0) for i in range(distinct.shape[0])])
    return distinct, means


def calibrate(config: dict, path, fs: float, columns: dict, robot) -> tuple[list, list[str]]:
    """``(calibrations, lines)``: the config's robot-alone and known-load files calibrated
    (``robot``: the model's, whose geometry is taken as known), and their tables as the
    script prints them. ``(None, [])`` without a ``[calibration]`` section. The files' and the
    calibrations' one-line ``ValueError``s come before ``identify`` starts."""
    section = config.get("calibration")
    if section is None:
        return None, []
    out, lines = [], []
    if section["robot_files"]:
        recordings = robot_recordings(section, path, fs, columns)
        cal = calibrate_robot(
            recordings, robot=robot, cutoff=section["cutoff"], min_rate=section["min_rate"] or MIN_RATE
        )
        out.append(cal)
        lines += [f"the robot alone: {len(recordings)} file(s)", cal.summary(), ""]
    if section["load_files"]:
        loads, readings = load_readings(section, path, columns)
        force = calibrate_force(loads, readings)
        out.append(force)
        lines += [f"the force transducer: {loads.shape[0]} known loads", force.summary(), ""]
    return out, lines


def record(calibrations) -> list[dict]:
    """Each calibration's labels, values, SEs and covariance (what ``identification.json`` holds)."""
    out = []
    for c in calibrations or []:
        values = np.concatenate([np.ravel(v) for v in c.values.values()])
        se = np.concatenate([np.ravel(v) for v in c.se.values()])
        entry = dict(kind=type(c).__name__, labels=list(c.labels), values=values, se=se, covariance=c.covariance)
        out.append(entry | ({"warnings": list(c.warnings)} if hasattr(c, "warnings") else {}))
    return out
