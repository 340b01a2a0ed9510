"""The loop linearised about its equilibrium (or along a reach), its Fisher information, and
the robot's Jacobian.

A namespace of the public face: ``import armimp_jax as aj; aj.linear.NAME`` (docs/design.md,
"The public names")."""

from __future__ import annotations

from ._identification.bound import fisher_information as fisher_information
from ._identification.linear import LinearLoop as LinearLoop
from ._identification.linear import drift as drift
from ._identification.linear import linearise as linearise
from ._model.robot import jacobian as jacobian

__all__ = ["LinearLoop", "drift", "fisher_information", "jacobian", "linearise"]
