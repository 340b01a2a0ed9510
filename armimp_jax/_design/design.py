"""Experiment design by gradient: the perturbation that gives the tightest estimates within a
patient's limits (``design``; the record length a precision needs is ``record.py``'s).

A design moves a perturbation family's ``shape`` (its spectrum, ``_model/families.py``) to
minimise a criterion of ``identify``'s predicted standard errors, for one trial or over a
set of trials (the patient's arm is what is unknown):

- ``criterion="max_relative_se"`` (default): the largest ``SE / |value|`` among the
  ``targets`` entries (e.g. the diagonals of M, B and K), over the trials (worst case) or
  averaged over them; smoothed for the gradient by a log-sum-exp of temperature
  ``SOFTMAX_TEMPERATURE`` (reported unsmoothed);
- ``criterion="d_optimal"``: the log-determinant of the targets' covariance in relative
  units (the volume of the confidence region).

Two methods predict the standard errors, each an object holding its own options (passed as
``design(..., method=...)``): ``CramerRao`` (the bound of the loop linearised about rest,
``bound_design.py``: deterministic, exact in its gradient, for near-linear loops; it can
design the controller's gains too and calibrate itself through the friction) and
``MonteCarlo`` (``predict.py``'s prediction through the friction-aware closed loop,
``monte_carlo_design.py``); ``Auto`` (the default) takes the first where it holds, else the
second. Both honour the limits by construction (``limits.py``). This module checks the
inputs and chooses the method.
"""

from __future__ import annotations

import dataclasses
from typing import ClassVar

import jax
import numpy as np

from .._checks import require_x64
from .._identification import layout as lay
from .._identification import linear
from .._identification.bound import is_near_linear, silent_readings
from .._model.families import Multisine, PaperNoise, ShapedNoise
from .._simulate import Trial
from .bound_design import BoundDesign, design_calibrated
from .criterion import DesignPlan, _targets
from .descent import optimizer_or_default
from .limits import DISPLACEMENT_TOLERANCE, Limits, _limited_signal, _peak_displacement
from .monte_carlo_design import Design, design_monte_carlo

CRITERIA = ("max_relative_se", "d_optimal")
METHODS = ("auto", "bound", "monte_carlo")  # the methods' names (configs, design.json)
AGGREGATES = ("worst", "mean")


def _count(where: str, name: str, value, low: int) -> None:
    if isinstance(value, bool) or not (isinstance(value, (int, np.integer)) and value >= low):
        raise ValueError(f"{where}: {name} must be an integer >= {low}, got {value!r}")


@dataclasses.dataclass(frozen=True)
class CramerRao:
    """Design on the Cramér-Rao bound (``bound_design.py``): deterministic and exact in its
    gradient, for near-linear loops (IMBIC, PD without friction).

    Args:
        controller: also design the controller's diagonal stiffness and damping (IMBIC's
            ``k_rd``, ``b_rd``; PD's ``kp``, ``kv``) within the limits.
        calibrate: rounds through the friction (0: the bound alone): ``predict_se`` over the
            bound per arm and target weighs the bound in a further round; the answer adds
            ``predicted_minutes``.
        precision: the relative half-width at 95% the minutes are reported for.
        draws: noise draws of each calibration's ``predict_se``."""

    controller: bool = False
    calibrate: int = 0
    precision: float = 0.1
    draws: int = 64
    name: ClassVar[str] = "bound"

    def __post_init__(self):
        _count("CramerRao", "calibrate", self.calibrate, 0)
        _count("CramerRao", "draws", self.draws, 8)
        if not isinstance(self.controller, bool):
            raise ValueError(f"CramerRao: controller must be True or False, got {self.controller!r}")
        if not (isinstance(self.precision, (int, float)) and 0 < self.precision < 1):
            raise ValueError(
                f"CramerRao: precision must lie in (0, 1) (relative half-width at 95%), got {self.precision!r}"
            )


@dataclasses.dataclass(frozen=True)
class MonteCarlo:
    """Design on ``identify``'s predicted SEs over noise draws through the friction-aware closed
    loop (``monte_carlo_design.py``): any loop, any free parameters and criterion.

    Args:
        draws: noise draws per trial per step (new ones every step).
        predict_draws: draws of the final ``predict_se`` before and after."""

    draws: int = 16
    predict_draws: int = 64
    name: ClassVar[str] = "monte_carlo"

    def __post_init__(self):
        _count("MonteCarlo", "draws", self.draws, 8)
        _count("MonteCarlo", "predict_draws", self.predict_draws, 8)


@dataclasses.dataclass(frozen=True)
class Auto:
    """``bound`` (a ``CramerRao``) where it covers the free parameters and the criterion and
    every arm's loop is near-linear under the starting signal, else ``monte_carlo``."""

    bound: CramerRao = CramerRao()
    monte_carlo: MonteCarlo = MonteCarlo()
    name: ClassVar[str] = "auto"


def _designable(family):
    if isinstance(family, PaperNoise):
        raise ValueError("design: PaperNoise has no shape to design; start from a ShapedNoise or a Multisine")
    if not isinstance(family, (ShapedNoise, Multisine)):
        raise ValueError(f"design: family must be a ShapedNoise or a Multisine, got {type(family).__name__}")


def _check_design(
    trial, family, free, limits, targets, criterion, robust_over, aggregate, steps, learning_rate, method
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
    _count("design", "steps", steps, 1)
    if not (isinstance(learning_rate, (int, float)) and 0 < learning_rate < 10):
        raise ValueError(f"design: learning_rate must lie in (0, 10) (a step in log amplitude), got {learning_rate!r}")
    if not isinstance(method, (CramerRao, MonteCarlo, Auto)):
        raise ValueError(
            "design: method must be aj.experiment.CramerRao(...), aj.experiment.MonteCarlo(...) or "
            f"aj.experiment.Auto(...), got {method!r}"
        )
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


def _choose_method(method, trials, candidates, layout, criterion, limits, key):
    """The ``CramerRao`` or ``MonteCarlo`` that runs: ``Auto`` takes its bound when the bound
    covers the free parameters and the criterion, and every arm's loop is near-linear under
    the starting signal; one-line errors for a method that cannot run here."""
    covered = all(n in lay.ARM_PARAMETERS for n in layout.names) and criterion == "max_relative_se"
    if isinstance(method, CramerRao):
        silent = [(i, names) for i, names in ((i, silent_readings(t)) for i, t in enumerate(trials)) if names]
        if silent:
            k, names = silent[0]
            raise ValueError(
                f"design: the bound (CramerRao) needs reading noise on every recorded channel; robust_over[{k}] "
                f"records {', '.join(names)} without any (acquisition {trials[k].acquisition!r}): "
                "use aj.experiment.MonteCarlo()"
            )
        if not covered:
            raise ValueError(
                "design: the bound (CramerRao) covers the arm's matrices with criterion='max_relative_se'; got free "
                f"{list(layout.names)}, criterion {criterion!r}"
            )
    if isinstance(method, Auto):
        near = False
        if covered and len(candidates) == 1:
            n = limits.n_samples(trials[0].period)
            f = _limited_signal(candidates[0], jax.random.split(key)[0], n, limits, trials[0].period)
            near = all(not silent_readings(t) and is_near_linear(t, f) for t in trials)
        if not near and (method.bound.controller or method.bound.calibrate):
            wanted = "the controller's gains" if method.bound.controller else "a calibration"
            raise ValueError(
                f"design: {wanted} needs the bound, which needs near-linear loops (IMBIC, or PD without friction) "
                "and one starting family; through stick-slip set the gains yourself (aj.experiment.MonteCarlo())"
            )
        method = method.bound if near else method.monte_carlo
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
    method: CramerRao | MonteCarlo | Auto = Auto(),
    steps: int = 40,
    learning_rate: float = 0.15,
    key=None,
    progress=None,
    optimizer=None,
) -> Design | BoundDesign:
    """Design the experiment: the ``family``'s spectrum (and, with ``CramerRao(controller=True)``,
    the controller's gains) that minimises ``criterion`` within ``limits``.

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
        method: ``CramerRao(...)`` (the bound: deterministic and exact in its gradient, for
            near-linear loops; with its options ``controller``, ``calibrate``, ``precision``,
            ``draws``), ``MonteCarlo(...)`` (``identify``'s predicted SEs over noise draws
            through the friction; ``draws``, ``predict_draws``), or ``Auto(...)`` (default):
            the bound where it covers the free parameters and every arm's loop is near-linear.
        steps, learning_rate: steps on the log of ``shape`` (and of the gains); Adam's rate.
        optimizer: an optax ``GradientTransformation`` (default ``optax.adam(learning_rate)``).
        key: ``jax.random`` key (default ``key(0)``): the family's own noise and every draw.
        progress: ``None`` or a callable ``progress(step, steps, value)`` called after each step.

    Returns a ``Design`` (Monte Carlo) or a ``BoundDesign`` (bound). One-line ``ValueError``
    before any long computation for an unknown parameter or target, a family with frequencies
    at or above the control rate's Nyquist frequency (checked by the family), limits no signal
    or controller can meet (a displacement limit no level of the starting signal meets, on
    every arm's full simulation, included), or a starting controller whose loop is unstable.
    """
    require_x64("design")
    optimizer = optimizer_or_default(optimizer, learning_rate, where="design")
    candidates, layout, idx, trials = _check_design(
        trial, family, free, limits, targets, criterion, robust_over, aggregate, steps, learning_rate, method
    )
    key = jax.random.key(0) if key is None else key
    designs_controller = isinstance(method, CramerRao | Auto) and (
        method.controller if isinstance(method, CramerRao) else method.bound.controller
    )
    if limits.drift is not None and not designs_controller:
        _check_fixed_drift(trials, limits.drift)
    _check_displacement(candidates, key, limits, trials)
    plan = DesignPlan(
        trials, free, layout, idx, limits, criterion, aggregate, steps, learning_rate, key, progress, optimizer
    )
    chosen = _choose_method(method, trials, candidates, layout, criterion, limits, key)
    if isinstance(chosen, CramerRao):
        return design_calibrated(
            plan,
            candidates[0],
            design_gains=chosen.controller,
            precision=chosen.precision,
            rounds=chosen.calibrate,
            draws=chosen.draws,
        )
    return design_monte_carlo(plan, candidates, draws=chosen.draws, predict_draws=chosen.predict_draws)


def _check_displacement(candidates, key, limits: Limits, trials) -> None:
    """A displacement limit that no level of the starting signal meets (on every arm's full
    noise-free simulation, at ``DISPLACEMENT_TOLERANCE`` of the force limits) is refused in one
    line before any design step."""
    if limits.peak_displacement is None:
        return
    if not all(linear.spectral_radius(linear.loop_of(t)) < 1.0 for t in trials):
        return  # an unstable loop: the controller's own check says so, in its words
    n = limits.n_samples(trials[0].period)
    fam_key = jax.random.split(key)[0]
    smallest = DISPLACEMENT_TOLERANCE
    for fam in candidates:
        f = _limited_signal(fam, fam_key, n, limits, trials[0].period, smallest)
        peaks = [float(_peak_displacement(t, f)[0]) for t in trials]
        if max(peaks) > limits.peak_displacement:
            raise ValueError(
                f"design: the hand's displacement stays above peak_displacement {limits.peak_displacement} m even at "
                f"{smallest:g} of the force limits ({1e3 * max(peaks):.3g} mm); raise it or lower the force limits"
            )
