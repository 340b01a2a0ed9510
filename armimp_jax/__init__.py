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
from typing import TYPE_CHECKING

from . import runtime as runtime  # JAX-free

__version__ = importlib.metadata.version("armimp_jax")  # pyproject.toml's, the one place it is written

# Public name -> the module that defines it, imported on first use (PEP 562).
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
    "no_arm": "._model.arm",
    "AbstractController": "._model.controllers",
    "controller_kind": "._model.controllers",
    "Admittance": "._model.controllers",
    "IMBIC": "._model.controllers",
    "PD": "._model.controllers",
    "AbstractFriction": "._model.friction",
    "friction_kind": "._model.friction",
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
    "LinearLoop": "._identification.linear",
    "linearise": "._identification.linear",
    "drift": "._identification.linear",
    "Identification": "._identification.identify",
    "identify": "._identification.identify",
    "IDENTIFY_NUMERICS": "._identification.indirect",
    "PredictedSE": "._identification.predict",
    "predict_se": "._identification.predict",
    "Limits": "._identification.limits",
    "Design": "._identification.monte_carlo_design",
    "design": "._identification.design",
    "CramerRao": "._identification.design",
    "MonteCarlo": "._identification.design",
    "Auto": "._identification.design",
    "record_for": "._identification.design",
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


if TYPE_CHECKING:  # what static tools and editors see
    from ._batch import MAX_PER_DEVICE as MAX_PER_DEVICE
    from ._batch import NumericsCheck as NumericsCheck
    from ._batch import TrialOutcome as TrialOutcome
    from ._batch import assess as assess
    from ._batch import assess_batch as assess_batch
    from ._batch import batch_groups as batch_groups
    from ._batch import check_numerics as check_numerics
    from ._batch import default_lanes as default_lanes
    from ._batch import make_mesh as make_mesh
    from ._batch import padded_batch_size as padded_batch_size
    from ._batch import shard_batch as shard_batch
    from ._batch import simulate_batch as simulate_batch
    from ._estimation.diagnose import FitDiagnostics as FitDiagnostics
    from ._estimation.diagnose import fit_warnings as fit_warnings
    from ._estimation.estimate import Estimate as Estimate
    from ._estimation.estimate import estimate as estimate
    from ._estimation.estimate import input_coherence as input_coherence
    from ._estimation.fit import fit_impedance as fit_impedance
    from ._estimation.impedance_fit import ImpedanceFit as ImpedanceFit
    from ._estimation.metrics import accuracy as accuracy
    from ._estimation.welch import Welch as Welch
    from ._estimation.welch import ZError as ZError
    from ._estimation.welch import cross_spectral_matrix as cross_spectral_matrix
    from ._estimation.welch import welch_segments as welch_segments
    from ._identification.bound import Bound as Bound
    from ._identification.bound import crlb as crlb
    from ._identification.bound import fisher_information as fisher_information
    from ._identification.bound_design import BoundDesign as BoundDesign
    from ._identification.design import Auto as Auto
    from ._identification.design import CramerRao as CramerRao
    from ._identification.design import MonteCarlo as MonteCarlo
    from ._identification.design import design as design
    from ._identification.design import record_for as record_for
    from ._identification.identify import Identification as Identification
    from ._identification.identify import identify as identify
    from ._identification.indirect import IDENTIFY_NUMERICS as IDENTIFY_NUMERICS
    from ._identification.limits import Limits as Limits
    from ._identification.limits import limited_signal as limited_signal
    from ._identification.linear import LinearLoop as LinearLoop
    from ._identification.linear import drift as drift
    from ._identification.linear import linearise as linearise
    from ._identification.monte_carlo_design import Design as Design
    from ._identification.predict import PredictedSE as PredictedSE
    from ._identification.predict import predict_se as predict_se
    from ._model.arm import Arm as Arm
    from ._model.arm import no_arm as no_arm
    from ._model.controllers import IMBIC as IMBIC
    from ._model.controllers import PD as PD
    from ._model.controllers import AbstractController as AbstractController
    from ._model.controllers import Admittance as Admittance
    from ._model.controllers import controller_kind as controller_kind
    from ._model.families import Multisine as Multisine
    from ._model.families import PaperNoise as PaperNoise
    from ._model.families import ShapedNoise as ShapedNoise
    from ._model.families import crest_factor as crest_factor
    from ._model.families import multisine as multisine
    from ._model.friction import NO_FRICTION as NO_FRICTION
    from ._model.friction import AbstractFriction as AbstractFriction
    from ._model.friction import CoulombViscous as CoulombViscous
    from ._model.friction import LuGre as LuGre
    from ._model.friction import friction_kind as friction_kind
    from ._model.friction import lugre as lugre
    from ._model.perturbation import perturbation as perturbation
    from ._model.plant import PlantState as PlantState
    from ._model.robot import MIT_MANUS as MIT_MANUS
    from ._model.robot import Robot as Robot
    from ._model.robot import jacobian as jacobian
    from ._model.sensors import Sensors as Sensors
    from ._model.voluntary import VoluntaryForce as VoluntaryForce
    from ._simulate import SimResult as SimResult
    from ._simulate import Trial as Trial
    from ._simulate import make_trial as make_trial
    from ._simulate import simulate as simulate
    from ._simulate import simulate_chunk as simulate_chunk
    from ._simulate import simulate_init as simulate_init
    from ._simulate import stack_trials as stack_trials
    from ._solver.ark import ARK3 as ARK3
    from ._solver.ark import ARK4 as ARK4
    from ._solver.graded import GradedARK4 as GradedARK4
    from ._solver.numerics import PAPER_NUMERICS as PAPER_NUMERICS
    from ._solver.numerics import SWEEP_NUMERICS as SWEEP_NUMERICS
    from ._solver.numerics import Numerics as Numerics
    from ._solver.rk4 import RK4 as RK4
