"""The paper's study, a client of the general simulator.

Presets (``trial``, ``arm``, ``friction``, ``perturbation_peak``) turn the paper's tables
into ``make_trial`` values; ``claims`` holds the experiments' conditions and the rules that
judge claims (a)-(f); ``reproduce``, ``report`` and ``plots`` run, report and draw the
reproduction; ``tune`` is the paper's Mhat-tuning experiment.
"""

from ..presets._paper import LOCATIONS as LOCATIONS
from ..presets._paper import arm as arm
from ..presets._paper import friction as friction
from ..presets._paper import location_endpoint as location_endpoint
from ..presets._paper import perturbation_peak as perturbation_peak
from ..presets._paper import trial as trial
