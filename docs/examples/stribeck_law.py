"""A lab's own friction law in one file, with no package change: a static Stribeck law.

    tau_f(v) = g(v) tanh(v / eps) + viscous v,   g(v) = tau_c + (tau_s - tau_c) exp(-(v / v_st)^2)

per joint (the torque resisting the joint's rate v [rad/s]). Defining the class registers the
kind "stribeck": a config names it, and the scripts load this file with --import:

    python sweeps/sweep.py --config docs/examples/stribeck.toml --import docs/examples/stribeck_law.py --out DIR

From Python, import this module before the config, sweep or design that names the kind. Its
slope for the implicit integrators is the forward-mode derivative of static_torque (the
default); its fields are per-joint pairs (aj.per_joint, which checks each one's range), the rule
across two of them checked in __check_init__ (docs/extending.md).
"""

from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import armimp_jax as aj


class Stribeck(aj.AbstractFriction):
    """Coulomb friction with a Stribeck peak at rest, smoothed over ``eps``, plus viscous."""

    kind: ClassVar[str] = "stribeck"
    UNITS: ClassVar[dict] = dict(tau_c="N m", tau_s="N m", v_st="rad/s", viscous="N m s/rad", eps="rad/s")
    STIFF_STATIC: ClassVar[bool] = True  # tanh(v / eps) is steep: the integrators take it implicitly
    IDENTIFIABLE: ClassVar[tuple] = ("tau_c",)

    tau_c: jnp.ndarray = aj.per_joint(minimum=0.0)
    tau_s: jnp.ndarray = aj.per_joint(0.0, minimum=0.0)  # 0: no peak (tau_s = tau_c)
    v_st: jnp.ndarray = aj.per_joint(0.01, minimum=0.0, exclusive=True)
    viscous: jnp.ndarray = aj.per_joint(0.0, minimum=0.0)
    eps: jnp.ndarray = aj.per_joint(1e-3, minimum=0.0, exclusive=True)

    def __check_init__(self):
        if isinstance(self.tau_c, jax.core.Tracer) or isinstance(self.tau_s, jax.core.Tracer):
            return  # built inside jit, vmap or grad: checked where the values are concrete
        tau_c, tau_s = np.asarray(self.tau_c), np.asarray(self.tau_s)
        if np.any((tau_s != 0) & (tau_s < tau_c)):
            raise ValueError(f"Stribeck: tau_s must be 0 or >= tau_c, got {tau_s.tolist()}")

    # one joint: the fields are scalars here
    def viscous_coefficient(self):
        return self.viscous

    def static_torque(self, v):
        peak = jnp.where(self.tau_s > 0, self.tau_s, self.tau_c)
        g = self.tau_c + (peak - self.tau_c) * jnp.exp(-((v / self.v_st) ** 2))
        return g * jnp.tanh(v / self.eps)

    # the whole law
    def without_coulomb(self):
        zero = jnp.zeros_like(self.tau_c)
        return eqx.tree_at(lambda law: (law.tau_c, law.tau_s), self, (zero, zero))

    def has_coulomb(self):
        return bool(np.any(np.asarray(self.tau_c) > 0) or np.any(np.asarray(self.tau_s) > 0))
