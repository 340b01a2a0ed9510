"""The paper's study, a client of the general simulator.

Presets (``trial``, ``arm``, ``friction``, ``perturbation_peak``) turn the paper's tables
into ``make_trial`` values; ``claims`` holds the experiments' conditions and the rules that
judge claims (a)-(f); ``reproduce``, ``report`` and ``plots`` run, report and draw the
reproduction; ``tune`` is the paper's Mhat-tuning experiment.
"""

from ._presets import LOCATIONS as LOCATIONS
from ._presets import arm as arm
from ._presets import friction as friction
from ._presets import location_endpoint as location_endpoint
from ._presets import perturbation_peak as perturbation_peak
from ._presets import trial as trial
