"""Perturbation families (the paper's noise, shaped noise, multisines) and signals held within
a patient's limits.

A namespace of the public face: ``import armimp_jax as aj; aj.signals.NAME`` (docs/design.md,
"The public names")."""

from __future__ import annotations

from ._design.limits import limited_signal as limited_signal
from ._model.families import Multisine as Multisine
from ._model.families import PaperNoise as PaperNoise
from ._model.families import ShapedNoise as ShapedNoise
from ._model.families import crest_factor as crest_factor
from ._model.families import multisine as multisine

__all__ = ["Multisine", "PaperNoise", "ShapedNoise", "crest_factor", "limited_signal", "multisine"]
