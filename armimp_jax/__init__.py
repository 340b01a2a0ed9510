"""armimp_jax: differentiable, vectorised simulation of stochastic human-arm impedance
estimation with a friction-afflicted planar robot under PD or IMBIC control.

The general simulator is at the top level (``make_trial``, ``simulate``, ``estimate``,
``accuracy``); the paper's presets and study are in ``armimp_jax.paper``.

Float64 is required: call ``jax.config.update("jax_enable_x64", True)`` before use
(the library never switches it on for you, and its entry points refuse to run without it).
"""

from . import runtime as runtime
from ._batch import NumericsCheck as NumericsCheck
from ._batch import TrialOutcome as TrialOutcome
from ._batch import Welch as Welch
from ._batch import assess as assess
from ._batch import assess_batch as assess_batch
from ._batch import check_numerics as check_numerics
from ._batch import simulate_batch as simulate_batch
from ._estimation.fit import ImpedanceFit as ImpedanceFit
from ._estimation.fit import fit_impedance as fit_impedance
from ._estimation.metrics import accuracy as accuracy
from ._estimation.welch import Estimate as Estimate
from ._estimation.welch import cross_spectral_matrix as cross_spectral_matrix
from ._estimation.welch import estimate as estimate
from ._estimation.welch import input_coherence as input_coherence
from ._model.arm import Arm as Arm
from ._model.control import IMBIC as IMBIC
from ._model.control import PD as PD
from ._model.friction import NO_FRICTION as NO_FRICTION
from ._model.friction import LuGre as LuGre
from ._model.friction import lugre as lugre
from ._model.perturbation import perturbation as perturbation
from ._model.plant import PlantState as PlantState
from ._model.robot import MIT_MANUS as MIT_MANUS
from ._model.robot import Robot as Robot
from ._model.sensors import Sensors as Sensors
from ._simulate import SimResult as SimResult
from ._simulate import Trial as Trial
from ._simulate import make_trial as make_trial
from ._simulate import simulate as simulate
from ._simulate import simulate_chunk as simulate_chunk
from ._simulate import simulate_init as simulate_init
from ._simulate import stack_trials as stack_trials
from ._solver.numerics import SWEEP_NUMERICS as SWEEP_NUMERICS
from ._solver.numerics import Numerics as Numerics

__version__ = "0.3.0"

runtime.apply_cpu_defaults()
