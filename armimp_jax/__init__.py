"""armimp_jax: differentiable, vectorised simulation of stochastic human-arm impedance
estimation with a friction-afflicted planar robot under PD, IMBIC or admittance control (or a
controller and a friction law of your own: ``AbstractController``, ``AbstractFriction``).

The general simulator is at the top level (``make_trial``, ``simulate``, ``estimate``,
``accuracy``); the paper's presets and study are in ``armimp_jax.paper``.

Float64 is required: call ``aj.runtime.configure()`` at program start, before any JAX
computation (float64, one CPU device per core, XLA:CPU's fast loops; see
``armimp_jax.runtime``), or at least ``jax.config.update("jax_enable_x64", True)``: the
library never switches it on for you, and its entry points refuse to run without it.

Importing ``armimp_jax`` does not import JAX and changes no setting of JAX's: each public
name is loaded on first use, so a script's ``--help`` answers at once.
"""

from __future__ import annotations

import importlib
import importlib.metadata

from . import runtime as runtime  # JAX-free

__version__ = importlib.metadata.version("armimp_jax")  # pyproject.toml's, the one place it is written

# The one list of public names: name -> the module that defines it, imported on first use
# (PEP 562). ``__all__`` and ``dir()`` read it; tests/test_exports.py holds it, ``__all__`` and
# the list in docs/design.md ("The public names") to each other.
_EXPORTS = {
    "MAX_PER_DEVICE": "._batch",
    "NumericsCheck": "._batch",
    "TrialOutcome": "._batch",
    "Welch": "._estimation.welch",
    "assess": "._batch",
    "assess_batch": "._batch",
    "batch_groups": "._batch",
    "check_numerics": "._batch",
    "default_lanes": "._batch",
    "make_mesh": "._batch",
    "padded_batch_size": "._batch",
    "shard_batch": "._batch",
    "simulate_batch": "._batch",
    "simulate_ensemble": "._batch",
    "Ensemble": "._estimation.ensemble",
    "EnsembleFit": "._estimation.ensemble_fit",
    "estimate_ensemble": "._estimation.ensemble_fit",
    "fit_warnings": "._estimation.diagnose",
    "ImpedanceFit": "._estimation.impedance_fit",
    "FitDiagnostics": "._estimation.diagnose",
    "fit_impedance": "._estimation.fit",
    "accuracy": "._estimation.metrics",
    "Estimate": "._estimation.estimate",
    "ZError": "._estimation.welch",
    "cross_spectral_matrix": "._estimation.welch",
    "estimate": "._estimation.estimate",
    "input_coherence": "._estimation.estimate",
    "welch_segments": "._estimation.welch",
    "Arm": "._model.arm",
    "MinimumJerk": "._model.movement",
    "Profile": "._model.movement",
    "no_arm": "._model.arm",
    "AbstractController": "._model.controllers",
    "controller_kind": "._model.controllers",
    "Admittance": "._model.controllers",
    "IMBIC": "._model.controllers",
    "PD": "._model.controllers",
    "AbstractFriction": "._model.friction",
    "friction_kind": "._model.friction",
    "per_joint": "._model.friction",
    "CoulombViscous": "._model.friction",
    "NO_FRICTION": "._model.friction",
    "LuGre": "._model.friction",
    "lugre": "._model.friction",
    "perturbation": "._model.perturbation",
    "PaperNoise": "._model.families",
    "ShapedNoise": "._model.families",
    "Multisine": "._model.families",
    "multisine": "._model.families",
    "crest_factor": "._model.families",
    "PlantState": "._model.plant",
    "MIT_MANUS": "._model.robot",
    "jacobian": "._model.robot",
    "Robot": "._model.robot",
    "Sensors": "._model.sensors",
    "VoluntaryForce": "._model.voluntary",
    "Bound": "._identification.bound",
    "crlb": "._identification.bound",
    "fisher_information": "._identification.bound",
    "PathBound": "._identification.path_bound",
    "Reaches": "._identification.path_bound",
    "reaches_for": "._identification.path_bound",
    "EnsembleIdentification": "._identification.ensemble_identify",
    "Envelope": "._identification.reach_design",
    "ReachDesign": "._identification.reach_design",
    "design_reach": "._identification.reach_design",
    "LinearLoop": "._identification.linear",
    "linearise": "._identification.linear",
    "drift": "._identification.linear",
    "Identification": "._identification.identify",
    "identify": "._identification.identify",
    "Recording": "._identification.pool",
    "RobotRecording": "._identification.robot_calibration",
    "RobotCalibration": "._identification.robot_calibration",
    "calibrate_robot": "._identification.robot_calibration",
    "ForceCalibration": "._identification.force_calibration",
    "calibrate_force": "._identification.force_calibration",
    "Sensitivity": "._identification.sensitivity",
    "robot_sensitivity": "._identification.sensitivity",
    "IDENTIFY_NUMERICS": "._identification.indirect",
    "PredictedSE": "._identification.predict",
    "predict_se": "._identification.predict",
    "Limits": "._identification.limits",
    "Design": "._identification.monte_carlo_design",
    "design": "._identification.design",
    "CramerRao": "._identification.design",
    "MonteCarlo": "._identification.design",
    "Auto": "._identification.design",
    "record_for": "._identification.record",
    "RecordLength": "._identification.record",
    "BoundDesign": "._identification.bound_design",
    "limited_signal": "._identification.limits",
    "SimResult": "._simulate",
    "Trial": "._simulate",
    "make_trial": "._simulate",
    "simulate": "._simulate",
    "simulate_chunk": "._simulate",
    "simulate_init": "._simulate",
    "stack_trials": "._simulate",
    "ARK3": "._solver.ark",
    "ARK4": "._solver.ark",
    "GradedARK4": "._solver.graded",
    "PAPER_NUMERICS": "._solver.numerics",
    "SWEEP_NUMERICS": "._solver.numerics",
    "Numerics": "._solver.numerics",
    "RK4": "._solver.rk4",
    "load_recording": ".study.recording",  # the study names here: a lab's first calls (no JAX)
    "load_ensemble": ".study.recording",
}
__all__ = sorted([*_EXPORTS, "runtime"])


def __getattr__(name: str):
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(module, __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))
