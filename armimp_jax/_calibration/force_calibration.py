"""Calibrating the force transducer against known static loads: ``calibrate_force`` and its answer
``ForceCalibration`` (docs/identification.md section 4d).

Per axis, the transducer reads ``gain * load + offset`` plus noise (docs/model.md section 8.1):
weights hung from the handle, or a known force pressed on it, each held still while it is
read. One least squares per axis gives the gain and the offset; their covariance rests on the
residuals' spread about the line, with ``n - 2`` degrees of freedom per axis, so the intervals
take Student's t (five loads leave three: t's 95% point is 3.18, not 1.96).
``identify(..., calibration=...)`` carries it into the arm's intervals as a normal prior whose
95% interval is the t one (``prior_covariance``).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.stats

from .._estimation.welch import check_finite
from .robot_calibration import table


@dataclasses.dataclass(frozen=True)
class ForceCalibration:
    """The force transducer's calibration (host values).

    Attributes:
        values: ``{"sensors.force_gain": (2,), "sensors.force_offset": (2,) [N]}`` per axis (the
            names ``identify`` frees).
        se: their standard errors; ``covariance`` ``(4, 4)`` in the order of ``labels`` (the
            axes independent: each axis's gain and offset correlate).
        dof: ``(2,)`` the residuals' degrees of freedom per axis (loads less 2).
        residual_sd: ``(2,)`` [N] the readings' spread about each axis's line.
        loads: the number of loads; warnings: plain sentences.
    """

    values: dict
    se: dict
    covariance: np.ndarray
    labels: list
    dof: np.ndarray
    residual_sd: np.ndarray
    loads: int
    warnings: list

    UNITS = {"sensors.force_gain": "-", "sensors.force_offset": "N"}

    def interval(self, name: str, level: float = 0.95):
        """Two-sided Student-t ``level`` interval ``(low, high)`` of ``name`` (each axis its own dof)."""
        t = scipy.stats.t.ppf(0.5 + level / 2, self.dof)
        return self.values[name] - t * self.se[name], self.values[name] + t * self.se[name]

    def prior_covariance(self) -> np.ndarray:
        """``covariance`` with each axis's entries scaled by ``(t / z)^2`` at 95%: a normal prior
        whose 95% interval is the t interval (what ``identify`` carries)."""
        scale = (scipy.stats.t.ppf(0.975, self.dof) / scipy.stats.norm.ppf(0.975)) ** 2
        s = np.sqrt(np.concatenate([scale, scale]))
        return self.covariance * s[:, None] * s[None, :]

    def summary(self) -> str:
        """The calibration as a Markdown table (Student-t intervals), then every warning."""
        sd = ", ".join(f"{a} {s:.3g} N" for a, s in zip("xy", self.residual_sd, strict=True))
        head = f"force calibration: {self.loads} loads, {int(self.dof[0])} degrees of freedom per axis; spread {sd}"
        return "\n".join([head, "", table(self), *("WARNING: " + w for w in self.warnings)])


def _checked(loads, readings):
    """``(loads (n, 2), readings (n, 2))`` [N] (raw readings per load averaged), one-line errors."""
    where = "calibrate_force"
    loads = np.asarray(loads, dtype=float)
    readings = np.asarray(readings, dtype=float)
    if loads.ndim != 2 or loads.shape[1] != 2:
        raise ValueError(f"{where}: loads must have shape (n, 2) [N], one known force per row, got {loads.shape}")
    if readings.shape[:1] != loads.shape[:1] or readings.shape[-1:] != (2,) or readings.ndim not in (2, 3):
        raise ValueError(
            f"{where}: readings must have shape ({loads.shape[0]}, 2), or ({loads.shape[0]}, m, 2) with m samples per "
            f"load, as loads {loads.shape}; got {readings.shape}"
        )
    check_finite("loads", loads, where=where, index="load")
    check_finite("readings", readings, where=where, index="load")
    if readings.ndim == 3:
        readings = readings.mean(axis=1)
    if loads.shape[0] < 3:
        raise ValueError(f"{where}: give at least 3 loads (2 leave no residual spread), got {loads.shape[0]}")
    for a, axis in enumerate("xy"):
        if np.ptp(loads[:, a]) <= 0:
            raise ValueError(
                f"{where}: the loads along {axis} are all equal ({loads[0, a]:g} N): give at least two different loads "
                "along each axis (a weight and none, say)"
            )
    return loads, readings


def calibrate_force(loads, readings) -> ForceCalibration:
    """The force transducer's gain and offset per axis from known static loads.

    Args:
        loads: ``(n, 2)`` [N] the known forces on the handle (x, y), one per row: weights
            hung (their mass times g, along the axis they pull), or a force pressed with a
            reference gauge; at least two different values along each axis, ``n >= 3``.
        readings: the transducer's readings [N] under each load: ``(n, 2)``, or ``(n, m, 2)``
            with ``m`` samples per load (averaged: the line's residuals, not the samples'
            spread, give the noise, so a load's placement error counts too).

    Returns a ``ForceCalibration``; each axis ``reading = gain * load + offset``. One-line
    ``ValueError`` for wrong shapes, NaN or inf, fewer than 3 loads, and loads all equal
    along an axis.
    """
    loads, readings = _checked(loads, readings)
    n = loads.shape[0]
    gain, offset, sd, cov = np.zeros(2), np.zeros(2), np.zeros(2), np.zeros((4, 4))
    for a in range(2):
        design = np.stack([loads[:, a], np.ones(n)], axis=1)
        coef, *_ = np.linalg.lstsq(design, readings[:, a], rcond=None)
        resid = readings[:, a] - design @ coef
        sd[a] = np.sqrt(resid @ resid / (n - 2))
        block = sd[a] ** 2 * np.linalg.inv(design.T @ design)
        gain[a], offset[a] = coef
        idx = [a, 2 + a]
        cov[np.ix_(idx, idx)] = block
    se = np.sqrt(np.diag(cov))
    warnings = []
    if np.any(gain <= 0):
        warnings.append(
            f"a gain came out at or below zero ({gain.tolist()}): check the loads' signs against the axes (a load "
            "along +x should read positive)"
        )
    return ForceCalibration(
        values={"sensors.force_gain": gain, "sensors.force_offset": offset},
        se={"sensors.force_gain": se[:2], "sensors.force_offset": se[2:]},
        covariance=cov,
        labels=["sensors.force_gain[0]", "sensors.force_gain[1]", "sensors.force_offset[0]", "sensors.force_offset[1]"],
        dof=np.full(2, float(n - 2)),
        residual_sd=sd,
        loads=n,
        warnings=warnings,
    )
