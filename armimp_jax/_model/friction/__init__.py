"""Joint friction laws: the extension point (``base.AbstractFriction``, its registry) and its
kinds, one per module (``lugre.LuGre``, ``coulomb_viscous.CoulombViscous``)."""

from .base import FRICTION_KINDS as FRICTION_KINDS
from .base import AbstractFriction as AbstractFriction
from .base import friction_kind as friction_kind
from .base import per_joint as per_joint
from .coulomb_viscous import CoulombViscous as CoulombViscous
from .lugre import G_FLOOR as G_FLOOR
from .lugre import NO_FRICTION as NO_FRICTION
from .lugre import LuGre as LuGre
from .lugre import bristle_g as bristle_g
from .lugre import bristle_g_and_slope as bristle_g_and_slope
from .lugre import lugre as lugre
from .lugre import steady_state_friction as steady_state_friction
from .lugre import stribeck as stribeck
