"""The registries of controllers and friction laws (a kind's class by its name), and the joint
state a controller's ``step`` may take.

A namespace of the public face: ``import armimp_jax as aj; aj.kinds.NAME`` (docs/design.md,
"The public names")."""

from __future__ import annotations

from ._model.controllers import Joints as Joints
from ._model.controllers import controller_kind as controller_kind
from ._model.friction import friction_kind as friction_kind

__all__ = ["Joints", "controller_kind", "friction_kind"]
