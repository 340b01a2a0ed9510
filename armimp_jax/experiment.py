"""Experiment design's settings: the clinical limits, the design methods, the reach's envelope
and its design, and the robot's sensitivity.

A namespace of the public face: ``import armimp_jax as aj; aj.experiment.NAME`` (docs/design.md,
"The public names")."""

from __future__ import annotations

from ._design.design import Auto as Auto
from ._design.design import CramerRao as CramerRao
from ._design.design import MonteCarlo as MonteCarlo
from ._design.limits import Limits as Limits
from ._design.reach_design import Envelope as Envelope
from ._design.reach_design import design_reach as design_reach
from ._design.sensitivity import robot_sensitivity as robot_sensitivity

__all__ = ["Auto", "CramerRao", "Envelope", "Limits", "MonteCarlo", "design_reach", "robot_sensitivity"]
