"""LuGre joint friction (docs/model.md section 4): the law (``LuGre``, kind ``"lugre"``) and its
pure per-joint functions.

``g(v) = tau_c + (tau_s - tau_c) exp(-(v/v_s)^2)``, ``zd = v - sigma0 |v| z / g(v)``,
``tau_f = sigma0 z + sigma1 zd + sigma2 v``. Where ``g(v) = 0`` (``tau_c = tau_s = 0``)
there are no bristles: ``zd = 0`` and ``tau_f = sigma2 v``, the limit of the model as
``tau_c -> 0``. ``NO_FRICTION`` (also ``sigma2 = 0``) is exactly zero friction; the
guarded division (double ``where``) keeps its values and gradients finite.

Functions act on scalars (one joint) and broadcast; batch with ``jax.vmap``. The
integrators reach them only through ``AbstractFriction``'s methods (``base.py``).
"""

from __future__ import annotations

import math
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..._checks import is_concrete
from ..._pytree import Param, replace_unchecked
from .base import AbstractFriction, per_joint

UNITS = dict(tau_c="N m", tau_s="N m", sigma0="N m/rad", sigma1="N m s/rad", sigma2="N m s/rad", v_s="rad/s")


class LuGre(AbstractFriction):
    """LuGre parameters of the two joints (an immutable pytree; every field ``(2,)`` float64,
    one value per joint; a scalar is used for both joints).

    Args:
        tau_c: Coulomb torque [N m], ``>= 0``.
        tau_s: stiction (static) torque [N m], ``>= tau_c``.
        sigma0: bristle stiffness [N m/rad], ``>= 0``.
        sigma1: bristle damping [N m s/rad], ``>= 0``.
        sigma2: viscous friction [N m s/rad], ``>= 0``.
        v_s: Stribeck velocity [rad/s], ``> 0``.

    Defaults for the bristles and viscosity are those of Canudas de Wit et al. (1995),
    which the paper adopts. Values are checked when concrete; tracers pass. Identify may
    free ``tau_c``, ``tau_s`` (kept above ``tau_c``) and the bristle and viscous parameters.
    """

    kind: ClassVar[str] = "lugre"
    UNITS: ClassVar[dict] = UNITS
    IDENTIFIABLE: ClassVar[tuple[str, ...]] = ("tau_c", "tau_s", "sigma0", "sigma1", "sigma2")

    tau_c: Param = per_joint(minimum=0.0)
    tau_s: Param = per_joint(minimum=0.0)
    sigma0: Param = per_joint(1e5, minimum=0.0)
    sigma1: Param = per_joint(math.sqrt(1e5), minimum=0.0)
    sigma2: Param = per_joint(0.5, minimum=0.0)
    v_s: Param = per_joint(1e-3, minimum=0.0, exclusive=True)

    def __check_init__(self):
        message = "LuGre: tau_s must be >= tau_c (stiction at least the Coulomb torque)"
        if is_concrete((self.tau_c, self.tau_s)):
            if np.any(np.asarray(self.tau_s) < np.asarray(self.tau_c)):
                tau_s, tau_c = np.asarray(self.tau_s).tolist(), np.asarray(self.tau_c).tolist()
                raise ValueError(f"{message}, got tau_s = {tau_s} and tau_c = {tau_c} N m")
            return
        bad = jnp.any(self.tau_s < self.tau_c)
        # a traced rule must ride on a field; no converter sees two fields and __check_init__ cannot assign
        object.__setattr__(self, "tau_s", eqx.error_if(self.tau_s, bad, message))

    def joint(self, i: int) -> LuGre:
        """The parameters of joint ``i`` (0 or 1) as scalars (what ``lugre`` takes)."""
        return replace_unchecked(self, **{name: getattr(self, name)[..., i] for name in UNITS})

    @classmethod
    def point_parameters(cls) -> dict:
        """A sweep point gives the stiction as a ratio to the Coulomb torque (``tau_c`` swept,
        the Stribeck curve's shape kept)."""
        out = super().point_parameters()
        del out["tau_s"]
        out["tau_c"] = (0.0, "N m")
        return {"tau_c": out.pop("tau_c"), "stiction_ratio": (1.5, "-"), **out}

    @classmethod
    def from_point(cls, values: dict) -> LuGre:
        values = dict(values)
        ratio = values.pop("stiction_ratio")
        return cls(tau_s=np.multiply(values["tau_c"], ratio), **values)  # per joint where tau_c is

    # one joint
    def torque_and_rate(self, v, z):
        return lugre(v, z, self)

    def viscous_coefficient(self):
        return self.sigma2

    def has_state(self):
        return self.tau_s > 0.0  # tau_s >= tau_c >= 0: g > 0 everywhere exactly when tau_s > 0

    def state_stiffness(self):
        return self.sigma0

    def state_damping(self):
        return self.sigma1

    def relaxation(self, v):
        """``lambda = sigma0 |v| / g(v)`` [1/s] and ``d lambda / dv`` [1/rad] (both 0 where the
        joint has no bristles)."""
        bristled = self.has_state()
        g, dg = bristle_g_and_slope(v, self)
        inv_g = 1.0 / jnp.where(bristled, g, 1.0)
        lam = jnp.where(bristled, self.sigma0 * jnp.abs(v) * inv_g, 0.0)
        dlam = jnp.where(bristled, self.sigma0 * (jnp.sign(v) - jnp.abs(v) * dg * inv_g) * inv_g, 0.0)
        return lam, dlam

    # the whole law
    def without_coulomb(self) -> LuGre:
        """No Coulomb or Stribeck torque (``tau_c = tau_s = 0``: no bristles), the viscous kept."""
        return replace_unchecked(self, tau_c=jnp.zeros_like(self.tau_c), tau_s=jnp.zeros_like(self.tau_s))

    def has_coulomb(self) -> bool:
        return bool(np.any(np.asarray(self.tau_s) > 0))

    def to_internal(self, names) -> dict:
        """Log scales, with stiction kept above the Coulomb torque as the law requires:
        ``tau_s = tau_c + exp(b)``; ``tau_c = exp(a)``, or ``tau_s sigmoid(a)`` when ``tau_s``
        is held fixed. (An optimiser left free to cross ``tau_s < tau_c`` was seen to dive there
        from a generic start: a Stribeck curve that rises with speed.)"""
        plain = [n for n in names if n not in ("tau_c", "tau_s")]
        out = super().to_internal(plain)
        tau_c, tau_s = np.asarray(self.tau_c, dtype=float), np.asarray(self.tau_s, dtype=float)
        if "tau_s" in names:
            if np.any(tau_s - tau_c <= 0):
                raise ValueError(
                    f"identify: friction.tau_s must start above tau_c to be estimated (tau_s = tau_c + exp(b)), got "
                    f"tau_s = {tau_s.tolist()} and tau_c = {tau_c.tolist()} N m"
                )
            out["tau_s"] = np.log(tau_s - tau_c)
            if "tau_c" in names:
                out.update(super().to_internal(["tau_c"]))
        elif "tau_c" in names:
            ratio = tau_c / tau_s
            if np.any(tau_c <= 0) or np.any(ratio >= 1):
                raise ValueError(
                    f"identify: friction.tau_c must start in (0, tau_s) to be estimated with tau_s held fixed, got "
                    f"tau_c = {tau_c.tolist()} and tau_s = {tau_s.tolist()} N m"
                )
            out["tau_c"] = np.log(ratio / (1.0 - ratio))
        return {n: out[n] for n in names}

    def from_internal(self, raw: dict) -> dict:
        out = super().from_internal({n: q for n, q in raw.items() if n not in ("tau_c", "tau_s")})
        if "tau_s" in raw:
            tau_c = jnp.exp(raw["tau_c"]) if "tau_c" in raw else self.tau_c
            if "tau_c" in raw:
                out["tau_c"] = tau_c
            out["tau_s"] = tau_c + jnp.exp(raw["tau_s"])
        elif "tau_c" in raw:
            out["tau_c"] = self.tau_s * jax.nn.sigmoid(raw["tau_c"])
        return out


# Exactly zero friction: no Coulomb, stiction or viscous torque, and no bristles. v_s = 1
# is a placeholder (never used where g = 0) that keeps v / v_s finite.
NO_FRICTION = LuGre(0.0, 0.0, sigma0=0.0, sigma1=0.0, sigma2=0.0, v_s=1.0)


def stribeck(v, p: LuGre):
    """``g(v) = tau_c + (tau_s - tau_c) exp(-(v/v_s)^2)`` [N m] (scalar parameters)."""
    # v times 1/v_s (within an ulp of v / v_s): in the simulation loop XLA hoists the
    # reciprocal, which saves a division per joint and RK4 stage.
    r = v * (1.0 / p.v_s)
    return p.tau_c + (p.tau_s - p.tau_c) * jnp.exp(-(r * r))


# Where tau_c = 0 < tau_s, g(v) = tau_s exp(-(v/v_s)^2) underflows to 0 beyond ~27 v_s, and the
# bristle rate sigma0 |v| / g with it: g is held at least G_FLOOR tau_s (a Coulomb torque of
# 1e-9 tau_s at speed), so a joint with stiction keeps its bristles at every velocity.
G_FLOOR = 1e-9


def bristle_g_and_slope(v, p: LuGre):
    """``g(v)`` [N m] as the bristle equations use it, ``stribeck`` held at least
    ``G_FLOOR tau_s`` (0 only where ``tau_s = 0``: no bristles), and ``dg/dv`` [N m s/rad]
    (0 where held; the stiff integrator's Newton step needs it)."""
    r = v * (1.0 / p.v_s)
    e = jnp.exp(-(r * r))
    g = p.tau_c + (p.tau_s - p.tau_c) * e  # stribeck(v, p), with its exponential kept for the slope
    floor = G_FLOOR * p.tau_s
    slope = jnp.where(g > floor, -2.0 * (p.tau_s - p.tau_c) * e * r * (1.0 / p.v_s), 0.0)
    return jnp.maximum(g, floor), slope


def bristle_g(v, p: LuGre):
    """``g(v)`` [N m] of ``bristle_g_and_slope``."""
    return bristle_g_and_slope(v, p)[0]


def lugre(v, z, p: LuGre):
    """Friction torque and bristle rate at joint velocity ``v`` [rad/s], bristle state ``z`` [rad].

    ``p`` holds one joint's parameters (``LuGre.joint``). Returns ``(tau_f, zd)``. Where
    ``g(v) = 0`` there are no bristles: ``zd = 0`` and ``tau_f = sigma2 v``.
    """
    g = bristle_g(v, p)
    positive = g > 0.0
    g_safe = jnp.where(positive, g, 1.0)
    # Written so that the g > 0 lanes compute bitwise what the unguarded formula does.
    zd = jnp.where(positive, v - jnp.where(positive, p.sigma0 * jnp.abs(v) * z / g_safe, 0.0), 0.0)
    tau = p.sigma0 * jnp.where(positive, z, 0.0) + p.sigma1 * zd + p.sigma2 * v
    return tau, zd


def steady_state_friction(v, p: LuGre):
    """Steady friction at constant velocity ``v``: ``g(v) sign(v) + sigma2 v`` [N m]."""
    return stribeck(v, p) * jnp.sign(v) + p.sigma2 * v
