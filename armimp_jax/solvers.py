"""The integrators, their presets, and a simulation stepped in chunks.

A namespace of the public face: ``import armimp_jax as aj; aj.solvers.NAME`` (docs/design.md,
"The public names")."""

from __future__ import annotations

from ._identification.indirect import IDENTIFY_NUMERICS as IDENTIFY_NUMERICS
from ._model.plant import PlantState as PlantState
from ._simulate import simulate_chunk as simulate_chunk
from ._simulate import simulate_init as simulate_init
from ._solver.ark import ARK3 as ARK3
from ._solver.ark import ARK4 as ARK4
from ._solver.graded import GradedARK4 as GradedARK4
from ._solver.numerics import PAPER_NUMERICS as PAPER_NUMERICS
from ._solver.numerics import SWEEP_NUMERICS as SWEEP_NUMERICS
from ._solver.rk4 import RK4 as RK4

__all__ = [
    "ARK3",
    "ARK4",
    "GradedARK4",
    "IDENTIFY_NUMERICS",
    "PAPER_NUMERICS",
    "PlantState",
    "RK4",
    "SWEEP_NUMERICS",
    "simulate_chunk",
    "simulate_init",
]
