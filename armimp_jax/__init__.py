"""armimp_jax: differentiable, vectorised simulation of stochastic human-arm impedance
estimation with a friction-afflicted MIT-MANUS robot under PD or IMBIC control.

Float64 is required: call ``jax.config.update("jax_enable_x64", True)`` before use
(the library never switches it on for you, and its entry points refuse to run without it).
"""

from .arm import ArmImpedance as ArmImpedance
from .arm import arm_impedance as arm_impedance
from .arm import true_impedance as true_impedance
from .control import ControllerGains as ControllerGains
from .control import ControllerMemory as ControllerMemory
from .estimate import Estimate as Estimate
from .estimate import cross_spectral_matrix as cross_spectral_matrix
from .estimate import estimate as estimate
from .estimate import input_coherence as input_coherence
from .friction import LuGreParams as LuGreParams
from .friction import friction_params as friction_params
from .friction import lugre as lugre
from .metrics import accuracy as accuracy
from .perturbation import perturbation as perturbation
from .perturbation import perturbation_peak as perturbation_peak
from .plant import PlantState as PlantState
from .simulate import SimResult as SimResult
from .simulate import TrialParams as TrialParams
from .simulate import simulate as simulate
from .simulate import stack_trials as stack_trials
from .simulate import trial_params as trial_params

__version__ = "0.1.0"
