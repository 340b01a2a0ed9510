"""Experiment design by gradient: the perturbation that gives the tightest estimates within a
patient's limits (``design``), and the record length a target needs (``record_for``).

A design moves a perturbation family's ``shape`` (its spectrum, ``_model/families.py``) to
minimise a criterion of ``identify``'s predicted standard errors, for one trial or over a
set of trials (the patient's arm is what is unknown):

- ``criterion="max_relative_se"`` (default): the largest ``SE / |value|`` among the
  ``targets`` entries (e.g. the diagonals of M, B and K), over the trials (worst case) or
  averaged over them; smoothed for the gradient by a log-sum-exp of temperature
  ``SOFTMAX_TEMPERATURE`` (reported unsmoothed);
- ``criterion="d_optimal"``: the log-determinant of the targets' covariance in relative
  units (the volume of the confidence region).

Two methods predict the standard errors: the Cramér-Rao bound of the loop linearised about
rest (``bound_design.py``: deterministic, exact in its gradient, for near-linear loops; it
can design the controller's gains too), and ``predict.py``'s Monte Carlo prediction through
the friction-aware closed loop (``monte_carlo_design.py``). Both honour the limits by
construction (``limits.py``). This module checks the inputs and chooses the method.
"""

from __future__ import annotations

import math

import jax
import numpy as np

from .._checks import check_choice, require_x64
from .._model.families import Multisine, PaperNoise, ShapedNoise
from .._simulate import Trial
from . import indirect, linear
from . import layout as lay
from .bound import is_near_linear, silent_readings
from .bound_design import BoundDesign, design_calibrated
from .criterion import DesignPlan, _targets, relative_se
from .limits import Limits, _limited_signal
from .monte_carlo_design import Design, design_monte_carlo
from .predict import STATISTICS, check_signal, predict_se

CRITERIA = ("max_relative_se", "d_optimal")
METHODS = ("auto", "bound", "monte_carlo")
AGGREGATES = ("worst", "mean")
CHECK_LIMIT_S = 3600.0  # [s] record_for predicts again at its answer only up to an hour


def _designable(family):
    if isinstance(family, PaperNoise):
        raise ValueError("design: PaperNoise has no shape to design; start from a ShapedNoise or a Multisine")
    if not isinstance(family, (ShapedNoise, Multisine)):
        raise ValueError(f"design: family must be a ShapedNoise or a Multisine, got {type(family).__name__}")


def _check_design(
    trial, family, free, limits, targets, criterion, robust_over, aggregate, counts, learning_rate, precision
):
    """``(candidates, layout, target indices, trials)``; one-line errors for bad inputs."""
    if not isinstance(trial, Trial):
        raise ValueError(f"design: trial must be a Trial (from make_trial), got {type(trial).__name__}")
    candidates = list(family) if isinstance(family, (list, tuple)) else [family]
    if not candidates:
        raise ValueError("design: family must be a family or a non-empty list of candidate families")
    for c in candidates:
        _designable(c)
    if criterion not in CRITERIA:
        raise ValueError(f"design: unknown criterion {criterion!r}; allowed: {', '.join(CRITERIA)}")
    if aggregate not in AGGREGATES:
        raise ValueError(f"design: unknown aggregate {aggregate!r}; allowed: {', '.join(AGGREGATES)}")
    if not isinstance(limits, Limits):
        raise ValueError(f"design: limits must be a Limits, got {type(limits).__name__}")
    layout = lay.make_layout(free, friction=getattr(trial, "friction", None), where="design")
    idx = _targets(layout, targets)
    trials = [trial] if robust_over is None else list(robust_over)
    if not trials or not all(isinstance(t, Trial) for t in trials):
        raise ValueError("design: robust_over must be a non-empty list of Trials")
    for i, t in enumerate(trials):
        if not t.noisy:
            raise ValueError(
                f"design: trial {i} has no noise (ideal sensors, no voluntary force): every design is exact"
            )
        same = (
            type(t.controller) is type(trial.controller),
            t.acquisition == trial.acquisition,
            t.period == trial.period,
        )
        if not all(same):
            raise ValueError(
                f"design: robust_over[{i}] must share the trial's controller type, acquisition and period; got "
                f"{type(t.controller).__name__}/{t.acquisition}/{t.period} s against "
                f"{type(trial.controller).__name__}/{trial.acquisition}/{trial.period} s"
            )
    for name, (v, low) in counts.items():
        if not (isinstance(v, (int, np.integer)) and v >= low):
            raise ValueError(f"design: {name} must be an integer >= {low}, got {v!r}")
    if not (isinstance(learning_rate, (int, float)) and 0 < learning_rate < 10):
        raise ValueError(f"design: learning_rate must lie in (0, 10) (a step in log amplitude), got {learning_rate!r}")
    if not 0 < precision < 1:
        raise ValueError(f"design: precision must lie in (0, 1) (relative half-width at 95%), got {precision!r}")
    return candidates, layout, idx, trials


def _check_fixed_drift(trials, limit):
    """A fixed controller must meet the drift limit itself (no design changes it): one line if not."""
    drifts = [float(linear.drift(t)) for t in trials]
    worst = int(np.argmax(drifts))
    if not drifts[worst] <= limit:
        raise ValueError(
            f"design: the controller lets the hand drift {1e3 * drifts[worst]:.2f} mm RMS under the person's force "
            f"at robust_over[{worst}], above the drift limit {1e3 * limit:g} mm; stiffen it, or design it "
            "(controller=True)"
        )


def _choose_method(method, controller, trials, candidates, layout, criterion, limits, key):
    """``"bound"`` or ``"monte_carlo"``: ``"auto"`` takes the bound when it covers the free
    parameters and the criterion, and every arm's loop is near-linear under the starting signal."""
    if method not in METHODS:
        raise ValueError(f"design: unknown method {method!r}; allowed: {', '.join(METHODS)}")
    covered = all(n in lay.ARM_PARAMETERS for n in layout.names) and criterion == "max_relative_se"
    silent = [(i, silent_readings(t)) for i, t in enumerate(trials)] if method == "bound" else []
    silent = [(i, names) for i, names in silent if names]
    if silent:
        raise ValueError(
            f"design: method='bound' needs reading noise on every recorded channel; robust_over[{silent[0][0]}] "
            f"records {', '.join(silent[0][1])} without any (acquisition {trials[silent[0][0]].acquisition!r}): "
            "use method='monte_carlo'"
        )
    if method == "bound" and not covered:
        raise ValueError(
            "design: method='bound' covers the arm's matrices with criterion='max_relative_se'; got free "
            f"{list(layout.names)}, criterion {criterion!r}"
        )
    if method == "auto":
        near = False
        if covered and len(candidates) == 1:
            n = limits.n_samples(trials[0].period)
            f = _limited_signal(candidates[0], jax.random.split(key)[0], n, limits, trials[0].period)
            near = all(not silent_readings(t) and is_near_linear(t, f) for t in trials)
        method = "bound" if near else "monte_carlo"
    if controller and method != "bound":
        raise ValueError(
            "design: controller=True designs the gains on the Cramér-Rao bound, which needs near-linear loops "
            "(IMBIC, or PD without friction) and one starting family; through stick-slip set the gains yourself"
        )
    return method


def design(
    trial: Trial,
    family,
    *,
    free,
    limits: Limits,
    targets=None,
    criterion: str = "max_relative_se",
    robust_over=None,
    aggregate: str = "worst",
    method: str = "auto",
    controller: bool = False,
    calibrate: int = 0,
    precision: float = 0.1,
    steps: int = 40,
    learning_rate: float = 0.15,
    draws: int = 16,
    predict_draws: int = 64,
    key=None,
    progress=None,
) -> Design | BoundDesign:
    """Design the experiment: the ``family``'s spectrum (and, with ``controller=True``, the
    controller's gains) that minimises ``criterion`` within ``limits``.

    Args:
        trial: the planned experiment (robot, controller, friction, sensors' and voluntary
            force's noise, and an arm: the truth assumed).
        family: the starting perturbation (``ShapedNoise`` or ``Multisine``); its ``shape``
            is designed, its level set by ``limits``. Or a list of candidate starts (e.g.
            ``ShapedNoise``s of several burst ``duty``s, which no gradient moves): each is
            predicted on the same draws and the design starts from the best
            (``Design.start_criteria``; Monte Carlo method only).
        free: the parameters ``identify`` will estimate (names as ``identify``).
        limits: ``Limits`` (RMS and peak force, peak displacement, record length; for the
            controller also the drift and the least stiffness and damping).
        targets: labels of the entries the criterion weighs (e.g. ``"arm.stiffness[0,0]"``);
            default every free entry but the off-diagonals of the matrices.
        criterion: ``"max_relative_se"`` or ``"d_optimal"`` (Monte Carlo method only).
        robust_over: trials to design for at once (e.g. one per arm the patient may have);
            default ``[trial]``. Each must share ``trial``'s controller type and acquisition.
        aggregate: ``"worst"`` (min-max) or ``"mean"`` over ``robust_over``.
        method: ``"bound"`` (the Cramér-Rao bound: deterministic and exact in its gradient,
            for near-linear loops: ``bound_design.py``), ``"monte_carlo"`` (``identify``'s
            predicted SEs over noise draws through the friction), or ``"auto"`` (default): the
            bound where it covers the free parameters and every arm's loop is near-linear.
        controller: also design the controller's diagonal stiffness and damping (IMBIC's
            ``k_rd``, ``b_rd``; PD's ``kp``, ``kv``) within ``limits`` (bound method only).
        calibrate: rounds through the friction (bound method; 0: the bound alone): ``predict_se``
            over the bound per arm and target weighs the bound in a further round; the answer
            adds ``predicted_minutes`` (``predict_se``'s, ``predict_draws`` draws).
        precision: the relative half-width at 95% the minutes are reported for (bound method).
        steps, learning_rate: Adam steps on the log of ``shape`` (and of the gains).
        draws: noise draws per trial per step (new ones every step; Monte Carlo method).
        predict_draws: draws of the final ``predict_se`` before and after (Monte Carlo method), or
            of each calibration's (bound method).
        key: ``jax.random`` key (default ``key(0)``): the family's own noise and every draw.
        progress: ``None`` or a callable ``progress(step, steps, value)`` called after each step.

    Returns a ``Design`` (Monte Carlo) or a ``BoundDesign`` (bound). One-line ``ValueError``
    before any long computation for an unknown parameter or target, a family with frequencies
    at or above the control rate's Nyquist frequency (checked by the family), limits no signal
    or controller can meet, or a starting controller whose loop is unstable.
    """
    require_x64("design")
    counts = {"steps": (steps, 1), "draws": (draws, 8), "predict_draws": (predict_draws, 8)}
    counts["calibrate"] = (calibrate, 0)  # rounds
    candidates, layout, idx, trials = _check_design(
        trial, family, free, limits, targets, criterion, robust_over, aggregate, counts, learning_rate, precision
    )
    key = jax.random.key(0) if key is None else key
    if limits.drift is not None and not controller:
        _check_fixed_drift(trials, limits.drift)
    plan = DesignPlan(trials, free, layout, idx, limits, criterion, aggregate, steps, learning_rate, key, progress)
    chosen = _choose_method(method, controller, trials, candidates, layout, criterion, limits, key)
    if chosen == "bound":
        return design_calibrated(
            plan, candidates[0], design_gains=controller, precision=precision, rounds=calibrate, draws=predict_draws
        )
    _check_calibrate(calibrate, chosen)
    return design_monte_carlo(plan, candidates, draws=draws, predict_draws=predict_draws)


def _check_calibrate(calibrate: int, method: str) -> None:
    """Calibration rounds (a count ``_check_design`` checked) refused in one line where the
    criterion has no bound to weigh (the Monte Carlo one: asked for, or chosen by ``"auto"``
    through stick-slip)."""
    if calibrate and method == "monte_carlo":
        raise ValueError(
            f"design: calibrate ({calibrate} rounds) weighs the bound; the Monte Carlo criterion has none "
            "(method 'monte_carlo', or 'auto' through stick-slip)"
        )


def record_for(
    trial: Trial,
    f,
    *,
    free,
    target: dict,
    statistic: str = "auto",
    draws: int = 64,
    key=None,
) -> dict:
    """The shortest record [s] at which ``identify``'s relative SE of each ``target`` entry
    reaches its goal, for the perturbation ``f`` ``(N, 2)`` (repeated or cut to length).

    ``target`` maps entry labels to relative SEs (``{"arm.stiffness[1,1]": 0.05}``: +-5% at
    one SE, about +-10% at 95%). ``statistic`` as ``identify``'s: ``"auto"`` (its default) takes
    the efficient statistic where the trial's loop is near-linear under ``f``, else Welch's;
    both predictions use the one chosen. From ``predict_se`` at the given length, SEs fall as
    one over the square root of the length (``tests/test_identify.py`` checks that law); the
    answer is then predicted again at that length (a second ``predict_se``, reported, not
    enforced: the law holds to the draws' noise). Returns ``{label: seconds}`` and
    ``"record_s"``, the longest of them, with the relative SEs predicted there (``"check"``;
    ``None`` past ``CHECK_LIMIT_S``, an hour: a record no session holds, which the check would
    simulate ``draws`` times) and the statistic used (``"statistic"``; Welch's where no arm
    matrix is free, as ``identify``)."""
    require_x64("record_for")
    check_choice("statistic", statistic, STATISTICS)
    layout = lay.make_layout(free, friction=getattr(trial, "friction", None), where="record_for")
    labels = layout.labels()
    if not isinstance(target, dict) or not target:
        raise ValueError(f"record_for: target must map entry labels to relative SEs, got {target!r}")
    bad = [t for t in target if t not in labels]
    if bad:
        raise ValueError(f"record_for: unknown target {bad[0]!r}; the free parameters' entries are {', '.join(labels)}")
    if not all(0 < float(v) < 1 for v in target.values()):
        raise ValueError(f"record_for: target relative SEs must lie in (0, 1), got {target}")
    f = np.asarray(f, dtype=float)
    period = trial.period
    statistic = _record_statistic(trial, f, layout, statistic)

    def relative(pred):
        return relative_se(pred, trial, free=free, targets=target)

    given = relative(predict_se(trial, f, free=free, statistic=statistic, draws=draws, key=key))
    seconds = f.shape[0] * period
    need = {t: seconds * (given[t] / float(target[t])) ** 2 for t in target}
    record_s = max(need.values())
    n = max(int(math.ceil(record_s / period)), 1000)
    if n * period > CHECK_LIMIT_S:  # the check would simulate every draw over that record
        return {**need, "record_s": n * period, "check": None, "statistic": statistic}
    longer = np.resize(f, (n, 2))  # repeats the perturbation (or cuts it)
    check = relative(predict_se(trial, longer, free=free, statistic=statistic, draws=draws, key=key))
    return {**need, "record_s": n * period, "check": check, "statistic": statistic}


def _record_statistic(trial: Trial, f, layout, statistic: str) -> str:
    """The statistic both of ``record_for``'s predictions use, decided once on the record given
    (the repeated one is the same signal) as ``identify`` decides it: Welch's where no arm
    matrix is free or the loop is not near-linear. ``f``'s own checks come first, one line
    each, before the simulation that decides."""
    check_signal(trial, f, "record_for")
    if indirect.arm_layout(layout) is None:
        return "welch"
    if statistic == "auto":
        return "efficient" if is_near_linear(trial, f) else "welch"
    return statistic
