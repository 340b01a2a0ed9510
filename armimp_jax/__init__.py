"""armimp_jax: differentiable, vectorised simulation of stochastic human-arm impedance
estimation with a friction-afflicted planar robot under PD, IMBIC or admittance control (or a
controller and a friction law of your own: ``AbstractController``, ``AbstractFriction``).

The top level holds a trial's parts and the calls a lab makes (``make_trial``, ``simulate``,
``estimate``, ``fit_impedance``, ``identify``, ``crlb``, ``design``; at most 40 names); the
rest lives in namespaces by purpose (``aj.batch``, ``aj.solvers``, ``aj.signals``,
``aj.spectra``, ``aj.linear``, ``aj.experiment``, ``aj.results``, ``aj.kinds``), the paper's
arms in ``armimp_jax.presets`` and its study in ``armimp_jax.paper``.

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
from typing import TYPE_CHECKING

from . import runtime as runtime  # JAX-free

if TYPE_CHECKING:  # what a type checker reads: every public name from its module (none loads here)
    from . import batch as batch
    from . import experiment as experiment
    from . import kinds as kinds
    from . import linear as linear
    from . import presets as presets
    from . import results as results
    from . import signals as signals
    from . import solvers as solvers
    from . import spectra as spectra
    from . import study as study
    from ._batch import simulate_batch as simulate_batch
    from ._batch import simulate_ensemble as simulate_ensemble
    from ._calibration.force_calibration import calibrate_force as calibrate_force
    from ._calibration.robot_calibration import RobotRecording as RobotRecording
    from ._calibration.robot_calibration import calibrate_robot as calibrate_robot
    from ._design.design import design as design
    from ._design.record import record_for as record_for
    from ._estimation.ensemble import Ensemble as Ensemble
    from ._estimation.ensemble_fit import estimate_ensemble as estimate_ensemble
    from ._estimation.estimate import estimate as estimate
    from ._estimation.fit import fit_impedance as fit_impedance
    from ._estimation.welch import Welch as Welch
    from ._identification.bound import crlb as crlb
    from ._identification.identify import identify as identify
    from ._identification.path_bound import reaches_for as reaches_for
    from ._identification.pool import Recording as Recording
    from ._identification.predict import predict_se as predict_se
    from ._model.arm import Arm as Arm
    from ._model.controllers import IMBIC as IMBIC
    from ._model.controllers import PD as PD
    from ._model.controllers import AbstractController as AbstractController
    from ._model.controllers import Admittance as Admittance
    from ._model.friction import NO_FRICTION as NO_FRICTION
    from ._model.friction import AbstractFriction as AbstractFriction
    from ._model.friction import CoulombViscous as CoulombViscous
    from ._model.friction import LuGre as LuGre
    from ._model.friction import per_joint as per_joint
    from ._model.movement import MinimumJerk as MinimumJerk
    from ._model.movement import Profile as Profile
    from ._model.perturbation import perturbation as perturbation
    from ._model.robot import Robot as Robot
    from ._model.sensors import Sensors as Sensors
    from ._model.voluntary import VoluntaryForce as VoluntaryForce
    from ._simulate import Trial as Trial
    from ._simulate import make_trial as make_trial
    from ._simulate import simulate as simulate
    from ._solver.numerics import Numerics as Numerics
    from .study.recording.recording import load_ensemble as load_ensemble
    from .study.recording.recording import load_recording as load_recording

__version__ = importlib.metadata.version("armimp_jax")  # pyproject.toml's, the one place it is written

# The one list of public names: name -> the module that defines it, imported on first use
# (PEP 562). ``__all__`` and ``dir()`` read it; tests/test_exports.py holds it, ``__all__`` and
# the list in docs/design.md ("The public names") to each other.
_EXPORTS = {
    "Arm": "._model.arm",
    "Robot": "._model.robot",
    "Sensors": "._model.sensors",
    "VoluntaryForce": "._model.voluntary",
    "Profile": "._model.movement",
    "MinimumJerk": "._model.movement",
    "Trial": "._simulate",
    "make_trial": "._simulate",
    "Numerics": "._solver.numerics",
    "Welch": "._estimation.welch",
    "AbstractController": "._model.controllers",
    "AbstractFriction": "._model.friction",
    "per_joint": "._model.friction",
    "PD": "._model.controllers",
    "IMBIC": "._model.controllers",
    "Admittance": "._model.controllers",
    "LuGre": "._model.friction",
    "CoulombViscous": "._model.friction",
    "NO_FRICTION": "._model.friction",
    "perturbation": "._model.perturbation",
    "simulate": "._simulate",
    "simulate_batch": "._batch",
    "simulate_ensemble": "._batch",
    "Ensemble": "._estimation.ensemble",
    "load_recording": ".study.recording.recording",
    "load_ensemble": ".study.recording.recording",
    "Recording": "._identification.pool",
    "RobotRecording": "._calibration.robot_calibration",
    "estimate": "._estimation.estimate",
    "fit_impedance": "._estimation.fit",
    "estimate_ensemble": "._estimation.ensemble_fit",
    "identify": "._identification.identify",
    "crlb": "._identification.bound",
    "predict_se": "._identification.predict",
    "design": "._design.design",
    "reaches_for": "._identification.path_bound",
    "record_for": "._design.record",
    "calibrate_robot": "._calibration.robot_calibration",
    "calibrate_force": "._calibration.force_calibration",
}
# Namespaces (modules), loaded on first use like the names: the rest of the library by purpose.
_NAMESPACES = (
    "batch",
    "solvers",
    "signals",
    "spectra",
    "linear",
    "experiment",
    "results",
    "kinds",
    "presets",
    "paper",
    "study",
)
# Names of earlier versions that moved into a namespace: a one-line error names the new place.
_MOVED = {
    "ARK3": "solvers",
    "ARK4": "solvers",
    "Auto": "experiment",
    "Bound": "results",
    "BoundDesign": "results",
    "CramerRao": "experiment",
    "Design": "results",
    "EnsembleFit": "results",
    "EnsembleIdentification": "results",
    "Envelope": "experiment",
    "Estimate": "results",
    "FitDiagnostics": "results",
    "ForceCalibration": "results",
    "GradedARK4": "solvers",
    "IDENTIFY_NUMERICS": "solvers",
    "Identification": "results",
    "ImpedanceFit": "results",
    "Limits": "experiment",
    "LinearLoop": "linear",
    "MAX_PER_DEVICE": "batch",
    "MIT_MANUS": "presets",
    "MonteCarlo": "experiment",
    "Multisine": "signals",
    "NumericsCheck": "results",
    "PAPER_NUMERICS": "solvers",
    "PaperNoise": "signals",
    "PathBound": "results",
    "PlantState": "solvers",
    "PredictedSE": "results",
    "RK4": "solvers",
    "ReachDesign": "results",
    "Reaches": "results",
    "RecordLength": "results",
    "RobotCalibration": "results",
    "SWEEP_NUMERICS": "solvers",
    "Sensitivity": "results",
    "ShapedNoise": "signals",
    "SimResult": "results",
    "TrialOutcome": "results",
    "ZError": "results",
    "accuracy": "spectra",
    "assess": "batch",
    "assess_batch": "batch",
    "batch_groups": "batch",
    "check_numerics": "batch",
    "controller_kind": "kinds",
    "crest_factor": "signals",
    "cross_spectral_matrix": "spectra",
    "default_lanes": "batch",
    "design_reach": "experiment",
    "drift": "linear",
    "fisher_information": "linear",
    "fit_warnings": "spectra",
    "friction_kind": "kinds",
    "input_coherence": "spectra",
    "jacobian": "linear",
    "limited_signal": "signals",
    "linearise": "linear",
    "make_mesh": "batch",
    "multisine": "signals",
    "no_arm": "presets",
    "padded_batch_size": "batch",
    "robot_sensitivity": "experiment",
    "shard_batch": "batch",
    "simulate_chunk": "solvers",
    "simulate_init": "solvers",
    "stack_trials": "batch",
    "welch_segments": "spectra",
}
_GONE = {"lugre": "LuGre(...).joint(i).torque_and_rate(v, z)"}
__all__ = sorted([*_EXPORTS, "runtime"])


if not TYPE_CHECKING:  # a type checker reads the imports above, and flags a name they lack

    def __getattr__(name: str):
        module = _EXPORTS.get(name)
        if module is not None:
            value = getattr(importlib.import_module(module, __name__), name)
        elif name in _NAMESPACES:
            value = importlib.import_module(f".{name}", __name__)
        elif name in _MOVED:
            raise AttributeError(f"armimp_jax.{name} is now armimp_jax.{_MOVED[name]}.{name}")
        elif name in _GONE:
            raise AttributeError(f"armimp_jax.{name} is gone: use {_GONE[name]}")
        else:
            raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
        globals()[name] = value
        return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS) | set(_NAMESPACES))
