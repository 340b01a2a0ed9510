"""How well must a lab know its robot? ``robot_sensitivity``: the bias a calibration error leaves
in the arm's estimates, per 1% error in each robot parameter, in standard errors.

``identify`` with the robot's parameters ``phi`` held at the lab's values solves
``beta(theta; phi_model) = b``, with ``b`` near ``beta(theta_true; phi_true)``. To first order
the estimate moves by

    d theta = -(A_t^T W A_t)^-1 A_t^T W A_p d phi,     A_t = d beta / d theta,  A_p = d beta / d phi,

the derivative of the estimate through the binding (``indirect.py``), with the statistics the
lab's own ``identify`` matches (of the arm alone). ``A_t`` and ``A_p`` are ``identify``'s
slope: the tangent (forward mode through the simulation) and, through friction, the binding's
chord (``indirect.chord``: over +-1 SE of each arm entry and +-``plausible`` percent of each
robot entry); the arm's SEs ``predict_se``'s covariance of those same draws and slope.
Robot parameters: the link inertias, the friction law's ``IDENTIFIABLE`` parameters and the
force channel's gain, each by 1% of its value (a parameter at zero has no 1%: it is left out,
and a force offset has no percentage). The force channel's
delay behind the position is zero in most models, so it has no 1% either: its column is per
millisecond, a secant of the binding from the model's delay to 1 ms more on the same draws (the
delay reads the recorded force by linear interpolation between samples, so its derivative at a
sample is one-sided; the delay leaves the loop alone, so the secant's draws differ only in the
recorded force).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from .._checks import require_x64
from .._identification import indirect
from .._identification import layout as lay
from .._identification.bound import ARM, has_friction, is_near_linear
from .._identification.predict import check_sampling, check_signal
from .._model.sensors import FORCE_HISTORY
from .._simulate import Trial
from .._solver.numerics import Numerics

DIAGONALS = ("[0,0]", "[1,1]")
DELAY = "sensors.force_delay"
DELAY_STEP_S = 1e-3  # the delay column's secant [s]: per millisecond


@dataclasses.dataclass(frozen=True)
class Sensitivity:
    """``robot_sensitivity``'s answer (host values).

    Attributes:
        bias_per_percent: ``(n_arm, n_robot)`` the move of each arm entry [its units] per 1%
            error in each robot parameter entry (the model's value 1% above the truth); the
            force delay's column (labelled ``... (per ms)``) per millisecond of the model's delay
            above the truth's (a truth 2 ms behind a model with none moves by -2 times it).
        in_se: the same over the arm entry's SE (``predict_se``).
        arm_labels, robot_labels: the rows' and columns' names.
        se: ``(n_arm,)`` the arm entries' SEs.
        plausible: the calibration error [%] the warnings are for.
        plausible_delay_ms: the force delay [ms] the delay's warning is for.
        warnings: per robot parameter that error would move an arm entry by more than one SE.
    """

    bias_per_percent: np.ndarray
    in_se: np.ndarray
    arm_labels: list
    robot_labels: list
    se: np.ndarray
    plausible: float
    warnings: list
    plausible_delay_ms: float = 1.0

    def table(self, *, diagonals: bool = True) -> str:
        """A Markdown table of ``in_se`` (the arm's diagonals by default)."""
        rows = [i for i, lab in enumerate(self.arm_labels) if not diagonals or lab.endswith(DIAGONALS)]
        head = "| arm entry | " + " | ".join(self.robot_labels) + " |"
        lines = [head, "|" + "---|" * (1 + len(self.robot_labels))]
        for i in rows:
            lines.append(f"| {self.arm_labels[i]} | " + " | ".join(f"{v:+.2f}" for v in self.in_se[i]) + " |")
        return "\n".join(lines)


def robot_names(trial: Trial) -> list[str]:
    """The robot's parameters to probe: those with a value to take 1% of (the inertias, the
    friction law's and the force gain), and the force channel's delay where the robot has a
    force transducer (its column per millisecond)."""
    names = ["robot.inertia"] + [f"friction.{n}" for n in type(trial.friction).IDENTIFIABLE]
    if trial.acquisition == "instant":  # the force channel's calibration is simulated only there
        names.append("sensors.force_gain")
    names = [n for n in names if np.all(np.asarray(lay._get(trial, n)) > 0)]
    return names + ([DELAY] if trial.acquisition == "instant" and not trial.sensors.motor_force else [])


def robot_sensitivity(
    trial: Trial,
    f,
    *,
    free=ARM,
    robot=None,
    plausible: float = 10.0,
    plausible_delay_ms: float = 1.0,
    statistic: str = "auto",
    numerics: Numerics | None = None,
    key=None,
    draws: int = 64,
    jacobian_draws: int = 8,
) -> Sensitivity:
    """The bias per 1% calibration error, for a planned experiment (module docstring).

    Args:
        trial: the planned experiment at its (assumed) true values, with its noise.
        f: the perturbation ``(N, 2)`` [N].
        free: the arm matrices ``identify`` will estimate.
        robot: the robot's parameters to probe (names as ``identify``'s: ``"robot.inertia"``,
            ``"friction.<name>"``, ``"sensors.force_gain"``, ``"sensors.force_delay"``, the last
            per millisecond); default ``robot_names(trial)``.
        plausible: the calibration error [%] the warnings are for.
        plausible_delay_ms: the force delay [ms] the delay's warning is for.
        statistic, numerics, key, draws, jacobian_draws: as ``predict_se``.

    Returns a ``Sensitivity``. One-line errors for names that are not arm matrices (``free``) or
    robot parameters (``robot``), and for a bad ``f``.
    """
    require_x64("robot_sensitivity")
    free, robot = _checked(trial, free, robot, plausible, plausible_delay_ms)
    delay = DELAY in robot
    step = _delay_step(trial) if delay else 0.0
    percent = tuple(n for n in robot if n != DELAY)
    est = lay.make_layout(free, friction=trial.friction, where="robot_sensitivity")
    both = lay.make_layout(free + percent, friction=trial.friction, where="robot_sensitivity")
    f = check_signal(trial, f, "robot_sensitivity")
    numerics, draws, jacobian_draws = check_sampling("robot_sensitivity", statistic, numerics, draws, jacobian_draws)
    key = jax.random.key(0) if key is None else key
    model = _calibrated(trial, robot)
    n_draws, n_jac = indirect.draw_counts(model, draws, jacobian_draws)
    keys = jax.random.split(key, n_draws)
    if statistic == "auto":  # as identify and predict_se choose
        statistic = "efficient" if is_near_linear(trial, f, numerics) else "welch"
    weight = None
    if statistic == "efficient" and has_friction(model):
        weight = indirect.statistic_weight(
            est, model, lay.pack(est, model), f, keys[: indirect.weight_draws(n_draws)], numerics
        )
    p_arm = lay.pack(est, model)
    arm_stat = indirect.arm_statistic(est, model, p_arm, f, weight) if statistic == "efficient" else None
    stats, _ = indirect.binding_draws(est, model, p_arm, f, keys, numerics, arm_stat)
    p = lay.pack(both, model)
    jac, diverged = indirect.binding_jacobian(both, model, p, f, keys[:n_jac], numerics, arm_stat, est)
    if bool(diverged):
        raise ValueError("robot_sensitivity: a noisy simulation of the trial diverged")
    jac = np.asarray(jac)
    if has_friction(model):  # identify's slope through friction is the binding's chord: so is this one's
        half = _chord_widths(est, both, model, np.asarray(p), jac, np.asarray(stats), n_draws, plausible)
        jac = _chord(both, est, model, p, f, keys[: indirect.chord_draws(n_draws)], numerics, arm_stat, half, jac)
    if delay:  # the per-ms column: a secant on the slope's own draws (module docstring)
        secant = _delay_secant(est, model, p_arm, f, keys[:n_jac], numerics, arm_stat, stats, step)
        jac = np.concatenate([jac, secant], axis=1)
    return _answer(est, both, model, np.asarray(p), np.asarray(stats), jac, n_draws, plausible, plausible_delay_ms)


def _chord_widths(est, both, model, p, jac, stats, n_draws, plausible) -> np.ndarray:
    """The chord's half-widths in ``both``'s internal units: the arm's SEs (from the tangent's
    covariance) and ``plausible`` percent of each robot entry."""
    n = est.size
    se = np.sqrt(np.diag(np.asarray(indirect.covariance(jac[:, :n], stats, n_draws))))
    if p.size == n:  # the delay alone: its column is a secant of its own
        return se
    per_percent = np.abs(np.diag(_per_percent(est, both, p, model)[1]))
    return np.concatenate([se, plausible * per_percent])


def _per_percent(est, both, p, model):
    """``(robot layout, (k, k))``: the robot parameters of ``both`` after ``est``'s, and the move
    of each one's internal value per 1% of each robot entry (its columns)."""
    k = len(est.names)
    robot_layout = lay.Layout(both.names[k:], both.symmetric[k:])
    q = jnp.asarray(p[est.size :])
    natural = np.asarray(lay.natural(robot_layout, q, model))
    d_nat = np.asarray(jax.jacfwd(lambda v: lay.natural(robot_layout, v, model))(q))
    return robot_layout, np.linalg.pinv(d_nat) @ np.diag(0.01 * natural)


def _chord(both, est, model, p, f, keys, numerics, arm_stat, half, tangent) -> np.ndarray:
    """``identify``'s chord (``search._slope``) of the binding in ``both``'s parameters, the
    tangent's column where a chord's draws diverged."""

    def means_at(points):
        return indirect.binding_means(both, model, points, f, keys, numerics, arm_stat, est)

    return indirect.chord(means_at, p, half, tangent)


def _checked(trial, free, robot, plausible, plausible_delay_ms) -> tuple[tuple, tuple]:
    """``(free, robot)`` as tuples, after the one-line refusals ``robot_sensitivity`` makes before
    any simulation."""
    if not isinstance(trial, Trial):
        raise ValueError(f"robot_sensitivity: trial must be a Trial, got {type(trial).__name__}")
    free = (free,) if isinstance(free, str) else tuple(free)
    if not free or any(n not in lay.ARM_PARAMETERS for n in free):
        raise ValueError(f"robot_sensitivity: free must name arm matrices ({', '.join(lay.ARM_PARAMETERS)})")
    if not trial.noisy:
        raise ValueError(
            "robot_sensitivity: the trial has no noise (ideal sensors, no voluntary force): no SE to weigh by"
        )
    robot = tuple(robot_names(trial) if robot is None else ((robot,) if isinstance(robot, str) else robot))
    if not robot or any(n in lay.ARM_PARAMETERS for n in robot):
        raise ValueError("robot_sensitivity: robot must name the robot's parameters (not the arm's)")
    for name, value, unit in (("plausible", plausible, "%"), ("plausible_delay_ms", plausible_delay_ms, " ms")):
        if not float(value) > 0.0:
            raise ValueError(f"robot_sensitivity: {name} must be > 0{unit}, got {value}")
    if DELAY in robot and trial.sensors.motor_force:
        raise ValueError("robot_sensitivity: a force from the motor torques has no force-channel delay to probe")
    if any(n.startswith("sensors.") for n in robot) and trial.acquisition != "instant":
        raise ValueError(
            "robot_sensitivity: the force channel's gain and delay need acquisition 'instant', got "
            f"{trial.acquisition!r}"
        )
    return free, robot


def _delay_step(trial: Trial) -> float:
    """The delay secant's step [s]: 1 ms later, or earlier where that would pass the delay
    line's end; a one-line error where neither fits (a period too short for 1 ms)."""
    delay, longest = float(trial.sensors.force_delay), (FORCE_HISTORY - 1) * trial.period
    if delay + DELAY_STEP_S < longest:
        return DELAY_STEP_S
    if delay - DELAY_STEP_S >= 0.0:
        return -DELAY_STEP_S
    raise ValueError(
        f"robot_sensitivity: the force delay line holds {1e3 * longest:g} ms at a {1e3 * trial.period:g} ms period, "
        f"too short to probe 1 ms about {1e3 * delay:g} ms"
    )


def _delay_secant(est, model, p_arm, f, keys, numerics, arm_stat, stats, step: float) -> np.ndarray:
    """``(m, 1)``: the binding's move per millisecond of the model's force delay, a secant of
    ``step`` [s] over the first draws (``keys``, those of ``stats``' first rows)."""
    later = float(model.sensors.force_delay) + step
    moved = dataclasses.replace(model, sensors=dataclasses.replace(model.sensors, force_delay=later))
    shifted, _ = indirect.binding_draws(est, moved, p_arm, f, keys, numerics, arm_stat)
    diff = (np.asarray(shifted) - np.asarray(stats)[: keys.shape[0]]).mean(axis=0)
    return (diff / (1e3 * step))[:, None]


def _calibrated(trial: Trial, robot) -> Trial:
    """The trial with its force channel simulated where its gain is probed (the same values)."""
    if any(n.startswith("sensors.") for n in robot) and not trial.sensors.calibrated:
        return dataclasses.replace(trial, sensors=dataclasses.replace(trial.sensors, calibrated=True))
    return trial


def _answer(est, both, model, p, stats, jac, n_draws, plausible, plausible_delay_ms) -> Sensitivity:
    """The table from the slope ``jac``: the arm's columns, each percent parameter's of
    ``both``, then (where one more) the delay's per-ms secant."""
    n = est.size
    w = np.asarray(indirect.weights(jnp.asarray(stats), jnp.asarray(jac[:, :n])))
    a_t, a_p = jac[:, :n], jac[:, n:]
    aw = a_t.T * w[None, :]
    move = -np.linalg.solve(aw @ a_t, aw @ a_p)  # internal arm per internal robot unit (per ms: the delay)
    # 1% of each robot entry in its internal units, and the arm's internal -> natural map
    q = p[n:]
    g = np.asarray(lay.natural_jacobian(est, jnp.asarray(p[:n]), model))
    bias, robot_labels = np.zeros((g.shape[0], 0)), []
    if q.size:
        robot_layout, per_percent = _per_percent(est, both, p, model)
        bias = g @ move[:, : q.size] @ per_percent
        robot_labels = robot_layout.labels()
    if move.shape[1] > q.size:  # the delay's column
        bias = np.concatenate([bias, g @ move[:, q.size :]], axis=1)
        robot_labels = [*robot_labels, f"{DELAY} (per ms)"]
    # predict_se's covariance, from the same draws and slope (not a second pass of them)
    se = np.sqrt(np.diag(g @ np.asarray(indirect.covariance(a_t, stats, n_draws)) @ g.T))
    in_se = bias / se[:, None]
    arm_labels = est.labels()
    warnings = []
    for j, lab in enumerate(robot_labels):
        worst = int(np.argmax(np.abs(in_se[:, j])))
        error = plausible_delay_ms if lab.startswith(DELAY) else plausible
        if abs(in_se[worst, j]) * error > 1.0:
            warnings.append(_warning(lab, arm_labels[worst], abs(in_se[worst, j]) * error, error))
    return Sensitivity(bias, in_se, arm_labels, robot_labels, se, float(plausible), warnings, float(plausible_delay_ms))


def _warning(label: str, entry: str, moved: float, error: float) -> str:
    """One warning, in the lab's terms, with what to do (``error``: in % or, the delay's, ms)."""
    if label.startswith(DELAY):
        return (
            f"a {error:g} ms error in the force channel's delay behind the position would move {entry} by "
            f"{moved:.1f} SE: measure the acquisition's delay (a tap on the handle shows it in both channels) or "
            "free sensors.force_delay in identify"
        )
    remedy = (
        "calibrate the force transducer against a known load"  # the robot alone reads no hand force
        if label.startswith("sensors.")
        else "calibrate it (free it in identify with a robot-alone recording under PD) or know it better"
    )
    return f"a {error:g}% error in the robot's {label} would move {entry} by {moved:.1f} SE: {remedy}"
