"""The registries of controllers and friction laws: a kind's class by its name.

A namespace of the public face: ``import armimp_jax as aj; aj.kinds.NAME`` (docs/design.md,
"The public names")."""

from __future__ import annotations

from ._model.controllers import controller_kind as controller_kind
from ._model.friction import friction_kind as friction_kind

__all__ = ["controller_kind", "friction_kind"]
