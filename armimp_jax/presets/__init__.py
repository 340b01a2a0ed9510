"""The paper's tables as named values (arms at four locations, friction and perturbation
levels) and ``trial``, which turns them into ``make_trial`` values. Below the studies: the
general sweep and the paper's reproduction both read them from here."""

from .._model.arm import no_arm as no_arm
from .._model.robot import MIT_MANUS as MIT_MANUS
from ._paper import LOCATIONS as LOCATIONS
from ._paper import PERTURBATION_LEVELS as PERTURBATION_LEVELS
from ._paper import arm as arm
from ._paper import friction as friction
from ._paper import location_endpoint as location_endpoint
from ._paper import perturbation_peak as perturbation_peak
from ._paper import trial as trial
from ._tables import LUGRE_DEFAULTS as LUGRE_DEFAULTS
