"""The human arm: a linear 2-DOF Cartesian impedance about an equilibrium endpoint (docs/model.md section 3).

``F_h = M_h xdd + B_h xd + K_h (x - x0)`` is the force applied to the hand [N];
``Z_h(s) = M_h s^2 + B_h s + K_h``. The matrices need not be symmetric and are used as
given. ``Arm`` is a single arm; stack arms (``jax.tree.map(jnp.stack, ...)``) or vmap over
them like any pytree.

During a movement (docs/model.md, "The arm during a movement") the damping and stiffness may be
``Profile``s and the endpoint a ``MinimumJerk`` path:
``F_h = M_h xdd + B_h(t) (xd - xd_e(t)) + K_h(t) (x - x_e(t))``.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from .._checks import as_param, check_positive_semidefinite
from .._pytree import Param, params
from .movement import MinimumJerk, Profile

UPPER_ARM_LENGTH = 0.21  # l_u [m]
FOREARM_LENGTH = 0.32  # l_f [m] (forearm plus hand)


def arm_endpoint(shoulder_rad, elbow_rad, *, upper=UPPER_ARM_LENGTH, forearm=FOREARM_LENGTH):
    """World-frame hand position [m] ``(2,)`` of a two-link arm (shoulder at the origin) with
    shoulder angle ``th_s`` and relative elbow angle ``th_e`` [rad] (docs/model.md section 3), NumPy."""
    return np.array(
        [
            upper * np.cos(shoulder_rad) + forearm * np.cos(shoulder_rad + elbow_rad),
            upper * np.sin(shoulder_rad) + forearm * np.sin(shoulder_rad + elbow_rad),
        ]
    )


@params
class Arm:
    """A human arm (an immutable pytree of float64 leaves).

    Args:
        mass: ``M_h`` ``(2, 2)`` [kg].
        damping: ``B_h`` ``(2, 2)`` [N s/m], or a ``Profile`` of it over time.
        stiffness: ``K_h`` ``(2, 2)`` [N/m], or a ``Profile`` of it over time.
        endpoint: ``x0`` ``(2,)`` [m], the hand's equilibrium in the world frame (origin at
            the shoulder); the robot holds the hand there at rest. Or a ``MinimumJerk`` path of
            the equilibrium: the arm then reaches, and the robot starts at rest at its ``start``.

    A profile with one knot is stored as its constant matrix. An arm whose endpoint is a path, or
    whose damping or stiffness changes with time, is ``moving``; ``at(t)`` is the still arm it is
    at time ``t``.

    The matrices may be non-symmetric. ``mass`` must have a positive semi-definite symmetric
    part (the coupled plant's inertia, the robot's plus ``J^T M_h J``, then stays invertible);
    damping and stiffness are free (a user may study unstable or negative-stiffness arms), so
    ``make_trial`` warns, in one line, rather than refuses an arm no human has (a mass diagonal
    outside 0.05-10 kg, a negative damping or stiffness diagonal: ``_model/plausibility.py``).
    All zero is no arm on the handle (``no_arm(endpoint)``: the robot alone). Values
    are checked when concrete; traced values pass, so ``grad`` and ``vmap`` flow through them.
    """

    mass: Param
    damping: Param  # or a Profile (a time profile along a reach)
    stiffness: Param  # or a Profile
    endpoint: Param  # or a MinimumJerk path

    def __post_init__(self):
        w = "Arm"
        if isinstance(self.mass, Profile):
            raise ValueError(f"{w}: mass stays constant during a movement: give a (2, 2) matrix [kg], not a Profile")
        for name, unit in (("mass", "kg"), ("damping", "N s/m"), ("stiffness", "N/m")):
            value = getattr(self, name)
            if isinstance(value, Profile):
                if value.knots == 1:  # a constant matrix (docs/model.md: then every result is a still arm's)
                    object.__setattr__(self, name, value.values[0])
                continue
            object.__setattr__(self, name, as_param(f"{name} [{unit}]", value, (2, 2), where=w))
        if not isinstance(self.endpoint, MinimumJerk):
            object.__setattr__(self, "endpoint", as_param("endpoint [m]", self.endpoint, (2,), where=w))
        object.__setattr__(self, "mass", check_positive_semidefinite("mass", self.mass, where=w, unit=" [kg]"))

    @property
    def moving(self) -> bool:
        """Whether the equilibrium follows a path or the damping or stiffness changes with time
        (known when tracing: it fixes the simulation's program)."""
        return any(isinstance(v, (Profile, MinimumJerk)) for v in (self.damping, self.stiffness, self.endpoint))

    @property
    def start(self):
        """The equilibrium at ``t = 0`` [m] ``(2,)``: the endpoint, or the path's start."""
        return self.endpoint.start if isinstance(self.endpoint, MinimumJerk) else self.endpoint

    def at(self, t) -> Arm:
        """The still arm this arm is at time ``t`` [s] (a scalar): ``B_h(t)``, ``K_h(t)`` and the
        equilibrium ``x_e(t)``; itself when it is not moving."""
        if not self.moving:
            return self

        def value(v):
            return v(t) if isinstance(v, Profile) else v

        end = self.endpoint.position(t) if isinstance(self.endpoint, MinimumJerk) else self.endpoint
        return Arm(self.mass, value(self.damping), value(self.stiffness), end)

    def impedance(self, f):
        """``Z_h(j 2 pi f)`` [N/m] ``(F, 2, 2)`` complex at frequencies ``f`` [Hz] ``(F,)`` (a still arm's;
        for a moving one, ``arm.at(t).impedance(f)``)."""
        if self.moving:
            raise ValueError("Arm.impedance: a moving arm has no single impedance; use arm.at(t).impedance(f)")
        return impedance_response(self, f)


def impedance_response(arm: Arm, f):
    """``M s^2 + B s + K`` at ``s = j 2 pi f`` for ``f`` [Hz] ``(F,)``: ``(F, 2, 2)`` complex [N/m]."""
    s = 2j * jnp.pi * jnp.asarray(f, dtype=jnp.float64)[:, None, None]
    return jnp.asarray(arm.mass)[None] * s**2 + jnp.asarray(arm.damping)[None] * s + jnp.asarray(arm.stiffness)[None]


def no_arm(endpoint) -> Arm:
    """No arm on the handle: zero mass, damping and stiffness, the robot held at ``endpoint`` [m]
    (a robot-alone recording; the hand force is then zero)."""
    zero = np.zeros((2, 2))
    return Arm(zero, zero, zero, endpoint)
