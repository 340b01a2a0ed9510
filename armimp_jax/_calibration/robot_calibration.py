"""Calibrating the robot from recordings of it alone: ``RobotRecording``, ``calibrate_robot`` and
its answer ``RobotCalibration`` (docs/identification.md section 4d).

The method is inverse-dynamics least squares (``idim.py``): the lab knows the command it sent
and measures the joint angles (or the hand position, through the robot's inverse kinematics);
the five-bar's inverse dynamics are linear in its inertia constants ``c1, c2, c3`` and in each
joint's static Coulomb and viscous friction, so one least squares over the samples where
every joint slides tells them, with a Newey-West covariance from the residuals. Quick (a pass
over the samples, no simulation) and not resting on a simulation's spread, so a robot-alone
recording with almost no noise is no harder than a noisy one. A recorded force (a transducer
with no one on the handle) tells the force channel's offset. ``identify(...,
calibration=...)`` carries the answer into the arm's intervals (``calibration_prior.py``).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time
from typing import NamedTuple

import jax
import numpy as np
import scipy.stats

from .._checks import require_x64
from .._estimation.welch import check_finite
from .._model.friction import CoulombViscous
from .._model.robot import MIT_MANUS, Robot, ik, jacobian_from_trig
from .._model.timing import CONTROL_PERIOD
from . import idim

MIN_RATE = 0.05  # [rad/s] a joint's row is kept where it slides at least this fast (module idim)
BAND_MULTIPLE = 2.5  # the default cut-off over the command's band
CUTOFF_WARN = 2.0  # a cut-off below this multiple of the band discards part of the perturbation's
MOTION_SE = 0.01  # an inertia told to worse than this relative SE: too little motion
STUCK_WARN = 0.10  # a joint kept for less than this share of the record: too much time stuck
# An inertia column whose sum of squares is more than this share the angles' noise: its compensation
# (a first-order correction) is then large enough to doubt (measured: 20% left the inertias 4-7 SE off)
NOISE_WARN = 0.05
MIN_KEPT = 200  # a joint needs at least this many kept samples in all
INERTIA_NAMES = ("c1", "c2", "c3")


class RobotRecording(NamedTuple):
    """One recording of the robot alone (no one on the handle), any controller, ``(N, 2)`` each:
    the hand position ``x`` [m] or the joint angles ``q`` [rad] (absolute, docs/model.md section
    2); the Cartesian command ``command`` [N] (``F_u``, the motors applying ``J^T F_u``;
    ``SimResult.fu``) or the motor torques ``torque`` [N m], each held over ``[t_k, t_k+1)``; the
    recorded force ``fh`` [N] (optional: with a transducer, its offset); ``period`` [s]."""

    x: object = None
    q: object = None
    command: object = None
    torque: object = None
    fh: object = None
    period: float = CONTROL_PERIOD


@dataclasses.dataclass(frozen=True)
class RobotCalibration:
    """The robot's calibration (host values).

    Attributes:
        values: ``{"robot.inertia": (3,) [kg m^2], "friction.tau_c": (2,) [N m],
            "friction.viscous": (2,) [N m s/rad]}``, and ``"sensors.force_offset"`` ``(2,)`` [N]
            where the recordings carry a force: the names ``identify`` frees (a LuGre model takes
            ``friction.viscous`` as its ``sigma2``).
        se: ``{name: array}`` their standard errors; ``covariance`` ``(n, n)`` in the order of
            ``labels`` (``"robot.inertia[0]"``, ...).
        robot: the model ``Robot`` with the calibrated inertia (the geometry is the model's).
        residual_rms: ``(2,)`` [N m] of the filtered torque equation over the kept samples.
        kept_fraction: ``(2,)`` share of the samples each joint's row was kept (it slid).
        cutoff, band: the filter's cut-off and the command's band [Hz]; lags: the Newey-West
            lag per recording [samples]; angle_noise: ``(2,)`` SD [rad] read from the angles.
        warnings: plain sentences: too little motion, too much time stuck, the cut-off against
            the perturbation's band.
        samples: samples over every recording; time_s: wall time of the call [s].
    """

    values: dict
    se: dict
    covariance: np.ndarray
    labels: list
    robot: Robot
    residual_rms: np.ndarray
    kept_fraction: np.ndarray
    cutoff: float
    band: float
    lags: tuple
    angle_noise: np.ndarray
    warnings: list
    samples: int
    time_s: float

    UNITS = {
        "robot.inertia": "kg m^2",
        "friction.tau_c": "N m",
        "friction.viscous": "N m s/rad",
        "sensors.force_offset": "N",
    }

    def interval(self, name: str, level: float = 0.95):
        """Two-sided normal ``level`` interval ``(low, high)`` of ``name``."""
        z = scipy.stats.norm.ppf(0.5 + level / 2)
        return self.values[name] - z * self.se[name], self.values[name] + z * self.se[name]

    def friction(self, v_s: float = 0.01) -> CoulombViscous:
        """The static law calibrated, as a ``CoulombViscous`` (``v_s`` its smoothing scale)."""
        return CoulombViscous(self.values["friction.tau_c"], self.values["friction.viscous"], v_s)

    def summary(self) -> str:
        """The calibration as a Markdown table with its settings, then every warning."""
        joints = ", ".join(f"joint {j + 1} {100 * f:.0f}%" for j, f in enumerate(self.kept_fraction))
        head = (
            f"robot calibration (inverse dynamics, least squares): {self.samples} samples; filter cut-off "
            f"{self.cutoff:.1f} Hz (the command's band {self.band:.1f} Hz); rows kept: {joints}; residual RMS "
            + ", ".join(f"joint {j + 1} {r:.3g} N m" for j, r in enumerate(self.residual_rms))
        )
        return "\n".join([head, "", table(self), *("WARNING: " + w for w in self.warnings)])


def table(cal) -> str:
    """A calibration's entries as a Markdown table: value, SE and 95% interval, with units."""
    lines = ["| entry | value | SE | 95% interval | unit |", "|---|---|---|---|---|"]
    for name, value in cal.values.items():
        low, high = cal.interval(name)
        for i in np.ndindex(np.shape(value)):
            label = f"{name}[{i[0]}]" if i else name
            if name == "robot.inertia":
                label += f" ({INERTIA_NAMES[i[0]]})"
            v, s = np.asarray(value)[i], np.asarray(cal.se[name])[i]
            interval = f"{np.asarray(low)[i]:.5g} to {np.asarray(high)[i]:.5g}"
            lines.append(f"| {label} | {v:.5g} | {s:.2g} | {interval} | {cal.UNITS[name]} |")
    return "\n".join(lines)


@functools.cache
def _inverse_kinematics():
    return jax.jit(jax.vmap(ik, in_axes=(0, None)))


def _angles(x, robot: Robot, where: str):
    """Joint angles ``(N, 2)`` of hand positions ``x`` (a one-line error for one out of reach)."""
    dx, dy = x[:, 0] - robot.base[0], x[:, 1] - robot.base[1]
    ls, le = float(robot.shoulder_link), float(robot.elbow_link)
    cos_d = (dx * dx + dy * dy - ls**2 - le**2) / (2.0 * ls * le)
    bad = np.flatnonzero(~(np.abs(cos_d) < 1.0))
    if bad.size:
        raise ValueError(
            f"{where}: x at sample {bad[0]}, {x[bad[0]].tolist()} m, is out of the robot's reach (check the units, m, "
            "and the robot's base and link lengths)"
        )
    return np.unwrap(np.asarray(_inverse_kinematics()(x, robot)), axis=0)


def _torque(q, command, robot: Robot):
    """The motor torques ``J(q)^T F_u`` [N m] ``(N, 2)``."""
    j11, j12, j21, j22 = jacobian_from_trig(robot, np.cos(q[:, 0]), np.sin(q[:, 0]), np.cos(q[:, 1]), np.sin(q[:, 1]))
    return np.stack([j11 * command[:, 0] + j21 * command[:, 1], j12 * command[:, 0] + j22 * command[:, 1]], axis=1)


def _array(name: str, a, where: str, n: int | None):
    arr = np.asarray(a, dtype=float)
    if arr.ndim != 2 or arr.shape[1] != 2 or (n is not None and arr.shape[0] != n):
        want = "(N, 2)" if n is None else f"({n}, 2), as the recording's other arrays"
        raise ValueError(f"{where}: {name} must have shape {want}, got {arr.shape}")
    check_finite(name, arr, where=where)
    return arr


def _one_of(r: RobotRecording, names: tuple[str, str], where: str) -> str:
    given = [n for n in names if getattr(r, n) is not None]
    if len(given) != 1:
        raise ValueError(f"{where}: give exactly one of {names[0]} and {names[1]}, got {given or 'neither'}")
    return given[0]


def _checked(recordings, robot: Robot, cutoff, min_rate: float):
    """Each recording's ``(q, tau, fh, period)``, checked in one line each before any work."""
    if isinstance(recordings, RobotRecording):
        recordings = [recordings]
    recordings = list(recordings)
    if not recordings or not all(isinstance(r, RobotRecording) for r in recordings):
        raise ValueError("calibrate_robot: recordings must be a RobotRecording or a non-empty list of them")
    if not isinstance(robot, Robot):
        raise ValueError(f"calibrate_robot: robot must be a Robot (the lab's model of it), got {type(robot).__name__}")
    if not (math.isfinite(min_rate) and min_rate > 0):
        raise ValueError(f"calibrate_robot: min_rate must be > 0 rad/s, got {min_rate}")
    out = []
    for i, r in enumerate(recordings):
        where = f"calibrate_robot: recording {i + 1}"
        if not (np.isfinite(r.period) and r.period > 0):
            raise ValueError(f"{where}: period must be > 0 s, got {r.period}")
        nyquist = 0.5 / r.period
        if cutoff is not None and not 0 < cutoff < nyquist:
            raise ValueError(
                f"{where}: cutoff must be in (0, {nyquist:g}) Hz, below its samples' Nyquist rate, got {cutoff} Hz"
            )
        position = _one_of(r, ("x", "q"), where)
        command = _one_of(r, ("command", "torque"), where)
        pos = _array(position, getattr(r, position), where, None)
        cmd = _array(command, getattr(r, command), where, pos.shape[0])
        fh = None if r.fh is None else _array("fh", r.fh, where, pos.shape[0])
        q = _angles(pos, robot, where) if position == "x" else np.unwrap(pos, axis=0)
        tau = _torque(q, cmd, robot) if command == "command" else cmd
        out.append((q, tau, fh, float(r.period)))
    return out


def _check_motion(q, period: float, taps, min_rate: float, where: str) -> None:
    """A one-line refusal for a recording too short for the filter, or one that does not move."""
    reach = idim.support(taps)
    if q.shape[0] < 10 * reach:
        raise ValueError(
            f"{where}: the record holds {q.shape[0]} samples; at this cut-off it needs at least {10 * reach} "
            "(record longer, or raise cutoff)"
        )
    rate = np.abs(idim.zero_phase(taps, idim.rates(q, period)[0]))[3 * reach : -3 * reach].max(axis=0)
    for j in range(2):
        if rate[j] < min_rate:
            raise ValueError(
                f"{where}: the robot does not move: joint {j + 1} never turns faster than {rate[j]:.3g} rad/s "
                f"(min_rate {min_rate:g} rad/s); record it alone under a perturbation that moves it (a larger one, "
                "or a softer controller)"
            )


def _cutoff(data, cutoff):
    """``(cutoff, band)`` [Hz]: the command's band (its widest over the recordings) and the
    cut-off, by default ``BAND_MULTIPLE`` times it (at most a quarter of the sample rate)."""
    band = max(idim.command_band(tau, 1.0 / period) for _, tau, _, period in data)
    if cutoff is None:
        cutoff = min(BAND_MULTIPLE * band, idim.NOISE_BAND / max(p for *_, p in data))
    return float(cutoff), band


def _offset(data):
    """``(offset (2,), covariance (2, 2))`` [N] of the recorded force (no one on the handle: the
    offset and the noise), Newey-West over each recording; ``None`` without a force."""
    forces = [fh for _, _, fh, _ in data if fh is not None]
    if not forces:
        return None
    n = sum(f.shape[0] for f in forces)
    mean = sum(f.sum(axis=0) for f in forces) / n
    meat = sum(idim.newey_west(f - mean, idim.andrews_lag(f - mean)) for f in forces)
    return mean, meat / n**2


def calibrate_robot(
    recordings, *, robot: Robot = MIT_MANUS, cutoff: float | None = None, min_rate: float = MIN_RATE, angle_noise=None
) -> RobotCalibration:
    """The robot's inertia constants, each joint's static Coulomb and viscous friction and the
    force offset, from recordings of the robot alone, by inverse-dynamics least squares.

    Args:
        recordings: a ``RobotRecording`` or a list of them (any controller; each a few seconds
            or more of motion: a perturbation under PD, say).
        robot: the lab's model of the robot: its link lengths and base (the kinematics) are
            taken as known; its inertia is what is calibrated.
        cutoff: the zero-phase filter's cut-off [Hz] (``idim.fir``), below the Nyquist rate;
            default ``BAND_MULTIPLE`` (2.5) times the command's band (the frequency below which
            99% of the commanded torque's power lies), at most a quarter of the sample rate.
        min_rate: [rad/s] a joint's sample is left out where its filtered rate falls below this
            anywhere within the filter's reach (the static law's sign is undefined there, and
            LuGre's bristles act).
        angle_noise: the angles' noise SD [rad] per joint (scalar or ``(2,)``; an encoder's
            count over ``sqrt(12)``); default read from the recordings (``idim.angle_noise``).

    Returns a ``RobotCalibration``. One-line ``ValueError`` before the least squares for: a
    recording without exactly one of ``x``/``q`` and of ``command``/``torque``, a wrong shape,
    NaN or inf, a position out of reach, a cut-off at or above the Nyquist rate, a record too
    short for the filter, and a robot that does not move (a joint never faster than
    ``min_rate``).
    """
    require_x64("calibrate_robot")
    t0 = time.perf_counter()
    data = _checked(recordings, robot, cutoff, min_rate)
    cutoff, band = _cutoff(data, cutoff)
    noise = None if angle_noise is None else np.broadcast_to(np.asarray(angle_noise, dtype=float), (2,)) ** 2
    taps = [idim.fir(cutoff, 1.0 / p) for *_, p in data]
    for i, ((q, _, _, period), t) in enumerate(zip(data, taps, strict=True)):
        _check_motion(q, period, t, min_rate, f"calibrate_robot: recording {i + 1}")
    rows = [idim.rows(q, tau, p, t, min_rate, noise) for (q, tau, _, p), t in zip(data, taps, strict=True)]
    kept = sum(r.keep.sum(axis=0) for r in rows)
    for j in np.flatnonzero(kept < MIN_KEPT):
        raise ValueError(
            f"calibrate_robot: joint {j + 1} slid faster than min_rate = {min_rate:g} rad/s for only {kept[j]} samples "
            f"(at least {MIN_KEPT}): record longer, or with a larger perturbation"
        )
    theta, cov, lags = idim.solve(rows)
    return _result(rows, theta, cov, lags, _offset(data), robot, (cutoff, band), time.perf_counter() - t0)


def _result(rows, theta, cov, lags, offset, robot, filtered, seconds) -> RobotCalibration:
    cutoff, band = filtered
    samples = sum(r.keep.shape[0] for r in rows)
    kept = sum(r.keep.sum(axis=0) for r in rows)
    square = sum((r.residual(theta) ** 2).sum(axis=0) for r in rows)
    values = {
        "robot.inertia": theta[idim.INERTIA],
        "friction.tau_c": theta[idim.COULOMB],
        "friction.viscous": theta[idim.VISCOUS],
    }
    if offset is not None:
        values["sensors.force_offset"] = offset[0]
        cov = np.block([[cov, np.zeros((cov.shape[0], 2))], [np.zeros((2, cov.shape[0])), offset[1]]])
    se_flat = np.sqrt(np.maximum(np.diag(cov), 0.0))
    se, labels, i = {}, [], 0
    for name, v in values.items():
        se[name] = se_flat[i : i + v.size]
        labels += [f"{name}[{k}]" for k in range(v.size)]
        i += v.size
    fraction = kept / samples
    variance = sum(r.variance for r in rows) / len(rows)
    return RobotCalibration(
        values=values,
        se=se,
        covariance=cov,
        labels=labels,
        robot=dataclasses.replace(robot, inertia=theta[idim.INERTIA]),
        residual_rms=np.sqrt(square / kept),
        kept_fraction=fraction,
        cutoff=cutoff,
        band=band,
        lags=lags,
        angle_noise=np.sqrt(variance),
        warnings=_warnings(values, se, fraction, filtered, idim.noise_fraction(rows)),
        samples=samples,
        time_s=seconds,
    )


def _warnings(values, se, fraction, filtered, noise) -> list[str]:
    """Plain warnings: too little motion, too much time stuck, the cut-off in the band, noisy
    accelerations."""
    cutoff, band = filtered
    out = []
    relative = se["robot.inertia"] / np.abs(values["robot.inertia"])
    weak = [f"{n} to {100 * r:.1f}%" for n, r in zip(INERTIA_NAMES, relative, strict=True) if r > MOTION_SE]
    if weak:
        out.append(
            f"the robot moved too little to tell its inertia ({', '.join(weak)}, SE over value): record longer or "
            "with a larger perturbation"
        )
    stuck = [f"joint {j + 1} {100 * (1 - f):.0f}%" for j, f in enumerate(fraction) if f < STUCK_WARN]
    if stuck:
        out.append(
            f"the joints were stuck or slow (below min_rate) for most of the record ({', '.join(stuck)} of the samples "
            "left out): the static friction law holds only while they slide; perturb harder or under a softer "
            "controller, or record longer"
        )
    if cutoff < CUTOFF_WARN * band:
        out.append(
            f"the filter's cut-off, {cutoff:.1f} Hz, is below {CUTOFF_WARN:g} times the command's band "
            f"({band:.1f} Hz): it discards part of the perturbation's motion, so the inertias are told less well; "
            "raise cutoff (the accelerations' noise grows with it) or perturb below half the cut-off"
        )
    if np.max(noise) > NOISE_WARN:
        out.append(
            f"the accelerations are {100 * np.max(noise):.0f}% encoder noise at this cut-off ({cutoff:.1f} Hz): the "
            "inertias' correction for it is large; lower cutoff, record with finer encoders, or perturb harder"
        )
    return out
