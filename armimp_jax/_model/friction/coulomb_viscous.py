"""A static friction law (docs/model.md section 4b): ``CoulombViscous``, kind ``"coulomb_viscous"``.

The torque on joint ``i`` is ``-tau_c tanh(qd / v_s) - viscous qd`` (KINARM's model, with
``tau_c`` about 0.06 N m, ``viscous`` about 0.0025 N m s/rad and ``v_s = 0.01`` rad/s), so the
torque resisting the motion is ``tau_f = tau_c tanh(v / v_s) + viscous v``. No internal
state. Its slope at rest, ``tau_c / v_s``, makes it stiff for small ``v_s``: the IMEX
integrators take the ``tanh`` part implicitly (``STIFF_STATIC``).
"""

from __future__ import annotations

from typing import ClassVar

import jax.numpy as jnp
import numpy as np

from ..._pytree import Param, replace_unchecked
from .base import AbstractFriction, per_joint

UNITS = dict(tau_c="N m", viscous="N m s/rad", v_s="rad/s")


class CoulombViscous(AbstractFriction):
    """A smoothed Coulomb torque plus viscous friction per joint (an immutable pytree; every
    field ``(2,)`` float64, one value per joint; a scalar is used for both joints).

    Args:
        tau_c: Coulomb torque [N m], ``>= 0``.
        viscous: viscous friction [N m s/rad], ``>= 0``.
        v_s: the ``tanh``'s velocity scale [rad/s], ``> 0`` (default 0.01, KINARM's ``100 v``).

    Values are checked when concrete; tracers pass. Identify may free ``tau_c`` and
    ``viscous`` (log scales).
    """

    kind: ClassVar[str] = "coulomb_viscous"
    UNITS: ClassVar[dict] = UNITS
    STIFF_STATIC: ClassVar[bool] = True
    IDENTIFIABLE: ClassVar[tuple[str, ...]] = ("tau_c", "viscous")

    tau_c: Param = per_joint(minimum=0.0)
    viscous: Param = per_joint(0.0, minimum=0.0)
    v_s: Param = per_joint(0.01, minimum=0.0, exclusive=True)

    # one joint
    def viscous_coefficient(self):
        return self.viscous

    def static_torque(self, v):
        return self.tau_c * jnp.tanh(v * (1.0 / self.v_s))

    def static_slope(self, v):
        t = jnp.tanh(v * (1.0 / self.v_s))
        return self.tau_c * (1.0 / self.v_s) * (1.0 - t * t)

    # the whole law
    def without_coulomb(self) -> CoulombViscous:
        return replace_unchecked(self, tau_c=jnp.zeros_like(self.tau_c))

    def has_coulomb(self) -> bool:
        return bool(np.any(np.asarray(self.tau_c) > 0))
