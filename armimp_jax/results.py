"""The types of what the calls return (for annotations and isinstance): simulations,
estimates, fits, identifications, bounds, designs and calibrations.

A namespace of the public face: ``import armimp_jax as aj; aj.results.NAME`` (docs/design.md,
"The public names")."""

from __future__ import annotations

from ._batch import NumericsCheck as NumericsCheck
from ._batch import TrialOutcome as TrialOutcome
from ._calibration.force_calibration import ForceCalibration as ForceCalibration
from ._calibration.robot_calibration import RobotCalibration as RobotCalibration
from ._design.bound_design import BoundDesign as BoundDesign
from ._design.monte_carlo_design import Design as Design
from ._design.reach_design import ReachDesign as ReachDesign
from ._design.record import RecordLength as RecordLength
from ._design.sensitivity import Sensitivity as Sensitivity
from ._estimation.diagnose import FitDiagnostics as FitDiagnostics
from ._estimation.ensemble_fit import EnsembleFit as EnsembleFit
from ._estimation.estimate import Estimate as Estimate
from ._estimation.impedance_fit import ImpedanceFit as ImpedanceFit
from ._estimation.welch import ZError as ZError
from ._identification.bound import Bound as Bound
from ._identification.ensemble_identify import EnsembleIdentification as EnsembleIdentification
from ._identification.identify import Identification as Identification
from ._identification.path_bound import PathBound as PathBound
from ._identification.path_bound import Reaches as Reaches
from ._identification.predict import PredictedSE as PredictedSE
from ._simulate import SimResult as SimResult

__all__ = [
    "Bound",
    "BoundDesign",
    "Design",
    "EnsembleFit",
    "EnsembleIdentification",
    "Estimate",
    "FitDiagnostics",
    "ForceCalibration",
    "Identification",
    "ImpedanceFit",
    "NumericsCheck",
    "PathBound",
    "PredictedSE",
    "ReachDesign",
    "Reaches",
    "RecordLength",
    "RobotCalibration",
    "Sensitivity",
    "SimResult",
    "TrialOutcome",
    "ZError",
]
