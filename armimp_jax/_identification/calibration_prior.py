"""A lab's calibrations carried into ``identify``: the robot's (``calibrate_robot``) and the force
transducer's (``calibrate_force``) values and covariance, as the nuisance prior of the
parameters they cover.

Without a calibration each nuisance (the friction's, the robot's, the force channel's)
carries a wide prior about its start (``search.PRIOR_SD`` on its internal scale). With one,
``identify(..., calibration=...)``:

1. sets every recording's model to the calibration's values (the robot's link inertias; the
   friction law's Coulomb torque, a LuGre model's stiction scaled with it, and its viscous
   friction, ``sigma2`` for LuGre; the force channel's gain and offset), free or not;
2. for those that are free, replaces their wide prior with the calibration's: its mean and its
   full covariance, carried to the internal scale through the parameters' own maps
   (``layout.py``: ``Sigma_int = G^-1 Sigma G^-T``, ``G`` the natural values' Jacobian there).

The search holds the prior as moments ``T p`` of the internal vector with the default's weight
and spread (``CalibratedPrior``): ``T = I`` for the default's entries and ``PRIOR_SD L^-1`` for a
calibration's (``Sigma_int = L L^T``), so the moments cost ``(p - mu)^T Sigma_int^-1 (p - mu)``
and the sandwich covariance carries ``Sigma_int``. Several calibrations that cover one parameter
(the force offset from the robot alone and from the loads) combine as independent
measurements (their information adds).
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import numpy as np

from .._model.friction import LuGre
from . import layout as lay
from . import pool as pl
from . import search
from .force_calibration import ForceCalibration
from .robot_calibration import RobotCalibration

GEOMETRY = ("shoulder_link", "elbow_link", "base")


class CalibratedPrior(NamedTuple):
    """The nuisance prior's moments ``root @ p[prior_index]`` (``(m, m)``) and which of them are a
    calibration's (``told``, ``(m,)``: never listed as barely told)."""

    root: np.ndarray
    told: np.ndarray


class Calibrated(NamedTuple):
    """The calibrations' parameters in ``identify``'s names for a friction law: the natural
    ``labels`` (``"robot.inertia[0]"``, ...), their ``mean`` and ``covariance``."""

    labels: tuple
    mean: np.ndarray
    covariance: np.ndarray

    def names(self) -> list[str]:
        return list(dict.fromkeys(lab.split("[")[0] for lab in self.labels))

    def value(self, name: str) -> np.ndarray:
        return np.array([m for lab, m in zip(self.labels, self.mean, strict=True) if lab.split("[")[0] == name])


def _items(calibration) -> list:
    items = list(calibration) if isinstance(calibration, (list, tuple)) else [calibration]
    for c in items:
        if not isinstance(c, (RobotCalibration, ForceCalibration)):
            raise ValueError(
                "identify: calibration must be a RobotCalibration (calibrate_robot), a ForceCalibration "
                f"(calibrate_force) or a list of them, got {type(c).__name__}"
            )
    return items


def _renamed(label: str, friction) -> str:
    """A calibration's label in the model's names: the static viscous friction is LuGre's ``sigma2``."""
    return label.replace("friction.viscous", "friction.sigma2") if isinstance(friction, LuGre) else label


def combine(calibration, friction) -> Calibrated:
    """The calibrations as one Gaussian over the union of their labels: each an independent
    measurement of its own, their information summed."""
    measured = []
    for c in _items(calibration):
        cov = c.prior_covariance() if isinstance(c, ForceCalibration) else c.covariance
        mean = np.concatenate([np.ravel(v) for v in c.values.values()])
        measured.append(([_renamed(lab, friction) for lab in c.labels], mean, cov))
    labels = list(dict.fromkeys(lab for m in measured for lab in m[0]))
    info, h = np.zeros((len(labels),) * 2), np.zeros(len(labels))
    for labs, mean, cov in measured:
        sel = np.zeros((len(labs), len(labels)))
        sel[np.arange(len(labs)), [labels.index(lab) for lab in labs]] = 1.0
        inv = np.linalg.inv(cov)
        info += sel.T @ inv @ sel
        h += sel.T @ inv @ mean
    covariance = np.linalg.inv(info)
    return Calibrated(tuple(labels), covariance @ h, covariance)


def _check_robot(calibration, trial, where: str) -> None:
    for c in _items(calibration):
        if not isinstance(c, RobotCalibration):
            continue
        ours, theirs = c.robot, trial.robot
        if not all(np.allclose(np.asarray(getattr(ours, g)), np.asarray(getattr(theirs, g))) for g in GEOMETRY):
            show = {g: np.asarray(getattr(ours, g)).tolist() for g in GEOMETRY}
            model = {g: np.asarray(getattr(theirs, g)).tolist() for g in GEOMETRY}
            raise ValueError(
                f"{where}: the calibration is of another robot ({show}) than the model's ({model}): calibrate this "
                "robot, or build the model with the calibrated robot's geometry"
            )


def calibrated_model(trial, cal: Calibrated):
    """``trial`` with the calibration's values in place (module docstring, step 1)."""
    names = cal.names()
    if "robot.inertia" in names:
        trial = dataclasses.replace(trial, robot=dataclasses.replace(trial.robot, inertia=cal.value("robot.inertia")))
    friction = {n.split(".")[1]: cal.value(n) for n in names if n.startswith("friction.")}
    if isinstance(trial.friction, LuGre) and "tau_c" in friction:  # the model's stiction keeps its ratio
        ratio = np.asarray(trial.friction.tau_s) / np.maximum(np.asarray(trial.friction.tau_c), 1e-300)
        friction["tau_s"] = friction["tau_c"] * np.where(np.asarray(trial.friction.tau_c) > 0, ratio, 1.0)
    if friction:
        trial = dataclasses.replace(trial, friction=dataclasses.replace(trial.friction, **friction))
    sensors = {n.split(".")[1]: cal.value(n) for n in names if n.startswith("sensors.")}
    if sensors:
        trial = dataclasses.replace(trial, sensors=dataclasses.replace(trial.sensors, **sensors))
    return trial


def apply(recordings, calibration):
    """``(recordings, Calibrated)``: every recording's model with the calibration in place
    (one-line errors for a calibration of another robot, or of parameters the model lacks)."""
    friction = recordings[0].model.friction
    cal = combine(calibration, friction)
    known = {"robot.inertia", "sensors.force_gain", "sensors.force_offset"} | {
        f"friction.{n}" for n in ("tau_c", "sigma2", "viscous") if hasattr(friction, n)
    }
    missing = [n for n in cal.names() if n not in known]
    if missing:
        raise ValueError(f"identify: the model's {type(friction).__name__} has no {', '.join(missing)} to calibrate")
    out = []
    for i, r in enumerate(recordings):
        where = "identify" if len(recordings) == 1 else f"identify: recording {i + 1}"
        _check_robot(calibration, r.model, where)
        out.append(r._replace(model=calibrated_model(r.model, cal)))
    return out, cal


def prior(pool: pl.Pool, p0, prior_index, cal: Calibrated | None) -> CalibratedPrior | None:
    """The search's prior moments (module docstring), or ``None`` where no free parameter is
    calibrated (the default's). One-line error for a calibrated parameter freed per group."""
    if cal is None:
        return None
    g = np.asarray(pl.natural_with_jacobian(pool, p0)[1])
    labels = pool.labels()
    rows, cols = [], []
    for b in pool.blocks:
        for name in b.layout.names:
            if name not in cal.names():
                continue
            if b.group is not None and pool.labelled:
                raise ValueError(f"identify: {name} is calibrated, so it must be shared (one robot), not per group")
            cols += list(b.slice.start + b.layout.index((name,)))
            rows += [labels.index(lab) for lab in labels if lab.split("[")[0] == name]
    if not cols or not np.all(np.isin(cols, prior_index)):  # none free, or a noise-free model (no prior)
        return None
    which = [cal.labels.index(labels[j]) for j in rows]
    g_cc = g[np.ix_(rows, cols)]
    sigma = np.linalg.solve(g_cc, np.linalg.solve(g_cc, cal.covariance[np.ix_(which, which)]).T)
    inner = np.linalg.inv(np.linalg.cholesky(0.5 * (sigma + sigma.T)))
    where = [int(np.flatnonzero(prior_index == c)[0]) for c in cols]
    root = np.eye(prior_index.size)
    root[np.ix_(where, where)] = search.PRIOR_SD * inner
    told = np.zeros(prior_index.size, dtype=bool)
    told[where] = True
    return CalibratedPrior(root, told)


def information(layout, trial, p, calibration):
    """``(n, n)`` on ``layout``'s internal scale at ``p``: the calibration's information about the
    free parameters it covers (zeros elsewhere), what ``predict_se`` adds; ``None`` without one.
    One-line error for a calibration of another robot than ``trial``'s."""
    if calibration is None:
        return None
    _check_robot(calibration, trial, "predict_se")
    cal = combine(calibration, trial.friction)
    zero = np.zeros((8, 2))
    pool = pl.make_pool([pl.Recording(trial, zero, zero, zero)], layout.names, (), ())
    prior_index = np.setdiff1d(np.arange(p.size), layout.index(tuple(lay.ARM_PARAMETERS)))
    made = prior(pool, np.asarray(p), prior_index, cal)
    out = np.zeros((p.size, p.size))
    if made is not None:
        told = prior_index[made.told]
        root = made.root[np.ix_(made.told, made.told)] / search.PRIOR_SD
        out[np.ix_(told, told)] = root.T @ root
    return out


def covariance(jac, stats, n_draws: int, info):
    """``indirect.covariance`` with a calibration's information ``info`` ``(n, n)`` added to the
    curvature and to the meat (its moments weighed by their own spread): traceable."""
    import jax.numpy as jnp

    from .indirect import weights

    w = weights(stats)
    aw = jac.T * w[None, :]
    omega = jnp.atleast_2d(jnp.cov(stats.T, ddof=1))
    h_inv = jnp.linalg.inv(aw @ jac + info)
    return h_inv @ ((1.0 + 1.0 / n_draws) * aw @ omega @ aw.T + info) @ h_inv
