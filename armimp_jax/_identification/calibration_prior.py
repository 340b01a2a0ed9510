"""A lab's calibrations carried into ``identify``: the robot's (``calibrate_robot``) and the force
transducer's (``calibrate_force``) values, and their uncertainty in the arm's intervals.

``identify(..., calibration=...)``:

1. sets every recording's model to the calibration's values (the robot's link inertias; the
   friction law's Coulomb torque, a LuGre model's stiction scaled with it, and its viscous
   friction, ``sigma2`` for LuGre; the force channel's gain and offset), and holds them there;
2. carries their covariance into the free parameters' covariance, as a two-step estimator's
   (Murphy and Topel, 1985): the estimate answers the calibration's error ``d c`` by ``d p = -S
   A_c d c`` (``S = H^-1 A^T W``, the search's sensitivity; ``A_c``, the binding's chord in the
   calibrated parameters, of the free parameters' own statistics), so the covariance gains
   ``S A_c Sigma_c A_c^T S^T``, ``Sigma_c`` the calibration's covariance on the internal scale
   (``layout.py``'s maps: ``G^-1 Sigma G^-T``).

Why not free the calibrated parameters with the calibration as their prior: freeing them adds
their own statistics to the match (the efficient statistic's scores for the inertias, the
friction's torque regression), which a person's recording under IMBIC barely tells and the
model matches less well than the arm's; measured on the protocol's case (seed 0), the arm then
settled 10-16 SE off (M[0,1], M[1,1], K[0,1], K[1,1]) while the same recording with the robot
known landed within 1.8 SE. Several calibrations that cover one parameter (the force offset
from the robot alone and from the loads) combine as independent measurements (their
information adds).
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from .._calibration.force_calibration import ForceCalibration
from .._calibration.robot_calibration import RobotCalibration
from .._model.friction import LuGre
from . import indirect, search
from . import layout as lay

GEOMETRY = ("shoulder_link", "elbow_link", "base")
# Calibrated parameters that identify may free instead of holding (the calibration's value then its
# start): the force channel's offset, which a person's recording tells far better than its
# calibration does and which the arm's stiffness answers steeply when held wrong (measured:
# docs/identification.md section 4d).
ESTIMABLE = ("sensors.force_offset",)


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

    def without(self, prefix: str) -> Calibrated:
        return self.only([n for n in self.names() if not n.startswith(prefix)])

    def without_names(self, names) -> Calibrated:
        return self.only([n for n in self.names() if n not in names])

    def only(self, names) -> Calibrated:
        """The calibrated parameters named in ``names`` (their marginal: mean and covariance block)."""
        keep = [i for i, lab in enumerate(self.labels) if lab.split("[")[0] in names]
        return Calibrated(tuple(self.labels[i] for i in keep), self.mean[keep], self.covariance[np.ix_(keep, keep)])


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
    if len(labels) == sum(len(m[0]) for m in measured):  # no parameter twice: their covariances side by side
        covariance = np.zeros((len(labels),) * 2)
        i = 0
        for labs, _, cov in measured:
            covariance[i : i + len(labs), i : i + len(labs)] = cov
            i += len(labs)
        return Calibrated(tuple(labels), np.concatenate([m[1] for m in measured]), covariance)
    info, h = np.zeros((len(labels),) * 2), np.zeros(len(labels))
    for labs, mean, cov in measured:
        sel = np.zeros((len(labs), len(labels)))
        sel[np.arange(len(labs)), [labels.index(lab) for lab in labs]] = 1.0
        inv = np.linalg.inv(cov)
        info += sel.T @ inv @ sel
        h += sel.T @ inv @ mean
    covariance = np.linalg.inv(info)
    return Calibrated(tuple(labels), covariance @ h, covariance)


def check_robot(calibration, trial, where: str) -> None:
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


def checked(calibration, friction, free, instant: bool, where: str) -> Calibrated:
    """The calibrations as one ``Calibrated`` (``combine``) for a model of ``friction``, the force
    channel's entries left out where it is not recorded on ``instant`` samples (the channel is
    simulated on those only). One-line errors for a parameter the model lacks or also named in
    ``free`` (but ``ESTIMABLE``'s, which ``free`` then estimates from the calibration's value)."""
    cal = combine(calibration, friction)
    if not instant:
        cal = cal.without("sensors.")
    free = (free,) if isinstance(free, str) else tuple(free)
    both = [n for n in cal.names() if n in free and n not in ESTIMABLE]
    if both:
        raise ValueError(
            f"{where}: {', '.join(both)} is calibrated: it is held at the calibration's value and its uncertainty "
            "carried into the intervals; leave it out of free"
        )
    known = {"robot.inertia", "sensors.force_gain", "sensors.force_offset"} | {
        f"friction.{n}" for n in ("tau_c", "sigma2", "viscous") if hasattr(friction, n)
    }
    missing = [n for n in cal.names() if n not in known]
    if missing:
        raise ValueError(f"{where}: the model's {type(friction).__name__} has no {', '.join(missing)} to calibrate")
    return cal


def apply(recordings, calibration, free):
    """``(recordings, Calibrated)``: every recording's model with the calibration in place, and
    what of it is held (``checked``; a calibration of another robot refused in one line). A
    calibrated parameter named in ``free`` (``ESTIMABLE``) starts at its calibration, and is not held."""
    instant = all(r.model.acquisition == "instant" for r in recordings)
    cal = checked(calibration, recordings[0].model.friction, free, instant, "identify")
    out = []
    for i, r in enumerate(recordings):
        where = "identify" if len(recordings) == 1 else f"identify: recording {i + 1}"
        check_robot(calibration, r.model, where)
        out.append(r._replace(model=calibrated_model(r.model, cal)))
    return out, cal.without_names([n for n in cal.names() if n in free])


# A calibrated parameter's chord spans at least this on its internal scale (1% of a log-scale
# value): its SE is far below the scale over which the binding through friction is smooth.
CHORD_FLOOR = 0.01


def layout_of(cal: Calibrated) -> lay.Layout:
    """The calibrated parameters as a layout (their internal maps: ``layout.py``'s)."""
    names = tuple(cal.names())
    return lay.Layout(names, (False,) * len(names))


def internal_covariance(cal: Calibrated, trial):
    """``(q, Sigma_int)``: the calibrated parameters' internal values in ``trial`` (which holds
    the calibration's values) and their covariance there, ``G^-1 Sigma G^-T``."""
    layout = layout_of(cal)
    q = np.asarray(lay.pack(layout, trial))
    g = np.asarray(lay.natural_jacobian(layout, jnp.asarray(q), trial))
    order = [cal.labels.index(lab) for lab in layout.labels()]
    sigma = cal.covariance[np.ix_(order, order)]
    return q, np.linalg.solve(g, np.linalg.solve(g, sigma).T)


def chord_columns(stat_layout, model, p, f, keys, numerics, arm_stat, cal: Calibrated, sigma_int):
    """``(m, n_c)``: the binding's chord (``indirect.chord``) in the calibrated parameters, of the
    statistics of ``stat_layout`` at its parameters ``p``, over ``+-max(3 SD, CHORD_FLOOR)``."""
    layout = layout_of(cal)
    both = lay.Layout(stat_layout.names + layout.names, stat_layout.symmetric + layout.symmetric)
    q = np.asarray(lay.pack(layout, model))
    point = np.concatenate([np.asarray(p, dtype=float), q])
    half = np.zeros(point.size)
    half[p.size :] = np.maximum(3.0 * np.sqrt(np.diag(sigma_int)), CHORD_FLOOR)
    moves = np.diag(half)[p.size :]
    means, diverged = indirect.binding_means(
        both, model, np.concatenate([point + moves, point - moves]), f, keys, numerics, arm_stat, stat_layout
    )
    if np.any(diverged):
        raise FloatingPointError("the calibration's chord: a simulation diverged")
    k = moves.shape[0]
    return (np.asarray(means[:k]) - np.asarray(means[k:])).T / (2.0 * half[p.size :])


def carried(problem, state) -> dict:
    """``{name: (n, n)}`` on the search's internal scale: each calibrated parameter's share of the
    free parameters' covariance at the search's answer (module docstring, step 2; the shares sum
    to the whole, ``Sigma_c``'s correlations between parameters split evenly); ``{}`` without a
    calibration, noise or slope."""
    cal = problem.calibration
    if cal is None or not cal.labels or not problem.noisy or state.jac is None:
        return {}
    _, sigma = internal_covariance(cal, problem.parts[0].model)
    draws = indirect.chord_draws(problem.n_draws)
    blocks = [
        chord_columns(
            part.layout,
            part.model,
            state.p[part.index],
            part.f,
            part.keys[:draws],
            problem.numerics,
            part.arm_stat,
            cal,
            sigma,
        )
        for part in problem.parts
    ]
    a_c = np.concatenate([*blocks, np.zeros((problem.prior_index.size, sigma.shape[0]))])
    w = search._weights(problem, state.stats, state.jac)
    move = search._sensitivity(state.jac, w) @ a_c
    layout = layout_of(cal)
    out = {}
    for k, name in enumerate(layout.names):
        own = np.zeros(sigma.shape[0])
        own[layout.index((name,))] = 1.0
        half = 0.5 * (own[:, None] + own[None, :])  # a cross term counts half to each of its two parameters
        out[name] = move @ (sigma * half) @ move.T
    return out


# An arm entry whose SE the calibration's uncertainty widens by more than this factor is warned of.
WIDEN_WARN = 2.0


def widening(shares: dict, cov_nat, g, labels) -> list[str]:
    """One warning naming the arm entries whose SE the calibration's uncertainty widens more than
    ``WIDEN_WARN`` times (``cov_nat``: the natural covariance without it; ``g``: natural over
    internal), and the calibrated parameter that takes most of it, with what to do."""
    if not shares:
        return []
    nat = {n: g @ s @ g.T for n, s in shares.items()}
    base = np.maximum(np.diag(cov_nat), 1e-300)
    ratio = np.sqrt(1.0 + sum(np.diag(s) for s in nat.values()) / base)
    wide = [j for j, lab in enumerate(labels) if lab.split("[")[0] in lay.ARM_PARAMETERS and ratio[j] > WIDEN_WARN]
    if not wide:
        return []
    worst = max(wide, key=lambda j: ratio[j])
    top = max(nat, key=lambda n: nat[n][worst, worst])
    entries = ", ".join(f"{labels[j]} {ratio[j]:.1f}x" for j in wide)
    remedy = (
        "free sensors.force_offset (the person's recording tells the offset far better than the robot alone does)"
        if top == "sensors.force_offset"
        else "calibrate with longer or livelier robot-alone recordings"
    )
    return [f"the calibration's uncertainty widens the arm's SEs ({entries}), most through {top}: {remedy}"]
