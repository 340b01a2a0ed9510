"""PD control (paper eq. 5, docs/model.md section 9.1): ``PD``, kind ``"pd"``."""

from __future__ import annotations

from typing import ClassVar

from ..._pytree import Param
from .base import AbstractController, gain_field, matvec

# Defaults as nested tuples (immutable): K_p [N/m], K_v [N s/m] (paper eq. 5)
PD_STIFFNESS = ((250.0, 0.0), (0.0, 250.0))
PD_DAMPING = ((4.0, 0.0), (0.0, 4.0))


class PD(AbstractController):
    """PD control (paper eq. 5): ``F_u = F_Delta - K_p (x - x0) - K_v xd``; during a movement
    ``F_u = F_Delta - K_p (x - x_d,k) - K_v (xd - xd_e,k)`` about the planned set point.

    Args:
        kp: ``K_p`` ``(2, 2)`` [N/m]; its symmetric part positive definite.
        kv: ``K_v`` ``(2, 2)`` [N s/m]; its symmetric part positive definite.

    Experiment design moves ``kp`` and ``kv``.
    """

    kind: ClassVar[str] = "pd"
    UNITS: ClassVar[dict] = dict(kp="N/m", kv="N s/m")
    DESIGN_GAINS: ClassVar[tuple[str, str]] = ("kp", "kv")

    kp: Param = gain_field(PD_STIFFNESS)
    kv: Param = gain_field(PD_DAMPING)

    def init(self, x0):
        return ()

    def step(self, memory, x, xd, fh, f_delta, x0, period, path=None):
        if path is None:
            return f_delta - matvec(self.kp, x - x0) - matvec(self.kv, xd), memory
        offset, velocity = path  # about the moving set point x_d,k = x0 + offset
        return f_delta - matvec(self.kp, (x - x0) - offset) - matvec(self.kv, xd - velocity), memory
