"""Experiment design's settings: the clinical limits, the design methods, the reach's envelope
and its design, and the robot's sensitivity.

A namespace of the public face: ``import armimp_jax as aj; aj.experiment.NAME`` (docs/design.md,
"The public names")."""

from __future__ import annotations

from ._identification.design import Auto as Auto
from ._identification.design import CramerRao as CramerRao
from ._identification.design import MonteCarlo as MonteCarlo
from ._identification.limits import Limits as Limits
from ._identification.reach_design import Envelope as Envelope
from ._identification.reach_design import design_reach as design_reach
from ._identification.sensitivity import robot_sensitivity as robot_sensitivity

__all__ = ["Auto", "CramerRao", "Envelope", "Limits", "MonteCarlo", "design_reach", "robot_sensitivity"]
