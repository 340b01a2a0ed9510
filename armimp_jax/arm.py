"""Human arm: the linear 2-DOF Cartesian impedance of each arm location (spec section 2, 10).

``F_h = M_h xdd + B_h xd + K_h (x - x0)`` is the force applied to the hand [N];
``Z_h(s) = M_h s^2 + B_h s + K_h``. The matrices are not symmetric and are used as
tabulated. Functions are single-location; ``true_impedance`` also accepts a traced
location index so it can be vmapped over locations.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from ._checks import check_choice, is_concrete
from .tables import ARM_LOCATIONS


class ArmImpedance(NamedTuple):
    """Arm impedance matrices, each ``(2, 2)`` float64: mass [kg], damping [N s/m], stiffness [N/m]."""

    mass: jnp.ndarray
    damping: jnp.ndarray
    stiffness: jnp.ndarray


LOCATIONS = tuple(ARM_LOCATIONS)


def arm_impedance(location: int) -> ArmImpedance:
    """Impedance matrices of arm location 1-4 (Table 2)."""
    check_choice("arm location", location, LOCATIONS)
    loc = ARM_LOCATIONS[location]
    return ArmImpedance(*(jnp.asarray(m, dtype=jnp.float64) for m in (loc.mass, loc.damping, loc.stiffness)))


_STACKED = {
    name: np.stack([getattr(ARM_LOCATIONS[k], name) for k in LOCATIONS]) for name in ("mass", "damping", "stiffness")
}


def true_impedance(location, f):
    """True arm impedance ``Z_h(j 2 pi f)`` [N/m], shape ``(F, 2, 2)`` complex, for ``f`` [Hz] ``(F,)``.

    ``location`` is 1-4: a Python int, or an integer array/tracer (so ``jax.vmap`` can map
    over locations; values are checked when concrete).
    """
    if is_concrete(location):
        loc = np.asarray(location)
        if loc.ndim != 0 or not np.issubdtype(loc.dtype, np.integer) or int(loc) not in LOCATIONS:
            raise ValueError(f"unknown arm location {location!r}; allowed: 1, 2, 3, 4")
    idx = jnp.asarray(location) - 1
    arm = ArmImpedance(*(jnp.asarray(_STACKED[n])[idx] for n in ("mass", "damping", "stiffness")))
    return impedance_response(arm, f)


def impedance_response(arm: ArmImpedance, f):
    """``M s^2 + B s + K`` at ``s = j 2 pi f`` for ``f`` [Hz] ``(F,)``: ``(F, 2, 2)`` complex [N/m]."""
    s = 2j * jnp.pi * jnp.asarray(f, dtype=jnp.float64)[:, None, None]
    return arm.mass[None] * s**2 + arm.damping[None] * s + arm.stiffness[None]
