"""The friction law as an extension point: ``AbstractFriction``, whose methods are everything
the simulator, the integrators, the linearisation and identification ask of a joint's
friction, and the registry of its kinds.

A law's torque ``tau_f`` [N m] resists the joint's rate ``v`` [rad/s]: the plant is
``M qdd + h + tau_f = tau_motor - J^T F_h`` (docs/model.md section 5), so a law whose torque
on the joint is ``-tau_c tanh(v / v_s) - viscous v`` has ``tau_f = tau_c tanh(v / v_s) +
viscous v``. A law is split into the parts the integrators treat differently:

- ``viscous_coefficient()``: a linear viscous coefficient [N m s/rad] (explicit, and in the linearised loop);
- a stiff *stateless* torque ``static_torque(v)`` with its slope ``static_slope(v)``
  (``STIFF_STATIC = True``): the IMEX integrators take it implicitly, like a damper whose
  coefficient may be huge (``tau_c / v_s`` at rest);
- a *bristle state* ``z`` [rad] of the LuGre/Dahl form ``z' = v - lambda(v) z``, acting as
  ``state_stiffness() z + state_damping() z'`` (``has_state``, ``relaxation``): the IMEX
  integrators take ``z`` implicitly.

The physics never imports an integrator: a law states its torque, its state's rate and
their slopes, and the integrators own the implicit solves (``armimp_jax/_solver``). A new
law is one class in one file: its fields (per-joint ``(2,)`` float leaves, ``per_joint()``; a
scalar is used for both joints) with ``UNITS``, ``kind``, ``viscous_coefficient`` and
``static_torque`` (its slope by ``jax.jvp`` unless the law gives ``static_slope``) or the
bristle methods, ``without_coulomb`` and ``has_coulomb`` (docs/extending.md).
Methods marked *one joint* act on ``joint(i)``, whose fields are scalars (they broadcast).
"""

from __future__ import annotations

import abc
import functools
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..._checks import as_param, check_range
from ..._pytree import show_fields
from .. import kinds

FRICTION_KINDS = kinds.Registry("friction")


def _per_joint_value(value, *, where, name, unit, minimum, exclusive):
    value = as_param(name if unit is None else f"{name} [{unit}]", value, (2,), where=where, broadcast=True)
    if minimum is None:
        return value
    unit = "" if unit is None else f" {unit}"
    return check_range(name, value, where=where, minimum=minimum, exclusive=exclusive, unit=unit)


def per_joint(default=kinds.REQUIRED, *, minimum: float | None = None, exclusive: bool = False, **kwargs):
    """A friction law's field holding one value per joint: float64 ``(2,)``, a scalar used for
    both joints, finite, and at least ``minimum`` (above it when ``exclusive``) when one is
    given. Concrete values are checked at once (a one-line ``ValueError`` naming the law, the
    field and its unit in ``UNITS``); traced ones carry the rules into the program, which
    raises when it runs (``equinox.error_if``). ``default`` as ``equinox.field`` takes it;
    other keywords pass through. A rule across fields goes in ``__check_init__``."""
    if default is not kinds.REQUIRED:
        kwargs["default"] = default
    check = functools.partial(_per_joint_value, minimum=minimum, exclusive=exclusive)
    return eqx.field(converter=kinds.Converter(check, where="per_joint", name="a per-joint value"), **kwargs)


class AbstractFriction(eqx.Module):
    """A joint friction law, the same form on both joints (an immutable pytree whose float
    leaves are ``(2,)``: one value per joint).

    Class attributes of a kind: ``kind`` (its name in configs, points and records),
    ``UNITS`` (every parameter's unit), ``STIFF_STATIC`` (whether ``static_torque`` is stiff
    and taken implicitly) and ``IDENTIFIABLE`` (the parameters ``identify`` may free: each
    estimated on a log scale unless the law maps it otherwise in ``to_internal`` /
    ``from_internal``).
    """

    kind: ClassVar[str]
    UNITS: ClassVar[dict]
    STIFF_STATIC: ClassVar[bool] = False
    IDENTIFIABLE: ClassVar[tuple[str, ...]] = ()

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        kinds.name_fields(cls)
        if "UNITS" in cls.__dict__:
            kinds.check_units(cls)
        FRICTION_KINDS.register(cls)

    __repr__ = show_fields

    # --- the schema: configs, sweep points, records ---------------------------------------

    @classmethod
    def parameters(cls) -> dict:
        """``{name: kinds.Parameter}`` of the law's parameters, each per joint ``(2,)``."""
        return kinds.parameters(cls, (2,))

    def record(self) -> dict:
        """The law as saved settings write it: ``{"type": kind, name: [joint 1, joint 2]}``."""
        return kinds.record(self, self.parameters())

    settings = record  # as a config's ``[friction]`` takes it

    @classmethod
    def point_parameters(cls) -> dict:
        """``{name: (default, unit)}`` of the law's settings in a sweep point (numbers, or a
        pair per joint); by default its parameters. ``from_point`` builds the law from them."""
        return {p.name: (p.default, p.unit) for p in cls.parameters().values()}

    @classmethod
    def from_point(cls, values: dict):
        """The law of a sweep point's settings (``point_parameters``' names)."""
        return cls(**values)

    def joint(self, i: int):
        """The parameters of joint ``i`` (0 or 1) as scalars: what the per-joint methods act on."""
        return jax.tree.map(lambda a: a[..., i], self)

    # --- one joint: the physics the integrators call ---------------------------------------

    def torque_and_rate(self, v, z):
        """One joint: the torque ``tau_f`` [N m] at rate ``v`` [rad/s] and state ``z`` [rad], and
        the state's rate ``z'`` [rad/s] (0 without a state). By default the sum of the parts."""
        zd = jnp.where(self.has_state(), v - self.relaxation(v)[0] * z, 0.0)
        tau = self.static_torque(v) + self.viscous_coefficient() * v
        return tau + jnp.where(self.has_state(), self.state_stiffness() * z + self.state_damping() * zd, 0.0), zd

    @abc.abstractmethod
    def viscous_coefficient(self):
        """One joint: the linear viscous coefficient [N m s/rad] (kept in the linearised loop)."""

    def static_torque(self, v):
        """One joint: the stateless nonlinear torque [N m] at rate ``v`` (0 by default)."""
        return jnp.zeros_like(v)

    def static_slope(self, v):
        """One joint: ``d static_torque / dv`` [N m s/rad] (what the implicit solve needs). By
        default the forward-mode derivative of ``static_torque``; a law may write its own."""
        return jax.jvp(self.static_torque, (v,), (jnp.ones_like(v),))[1]

    def has_state(self):
        """One joint: whether it has a bristle state (a bool, possibly traced)."""
        return False

    def state_stiffness(self):
        """One joint: the torque per unit of bristle state [N m/rad] (``sigma0``)."""
        return 0.0

    def state_damping(self):
        """One joint: the torque per unit of bristle rate [N m s/rad] (``sigma1``)."""
        return 0.0

    def relaxation(self, v):
        """One joint: the bristle relaxation rate ``lambda(v)`` [1/s] of ``z' = v - lambda z``
        and its slope ``d lambda / dv`` [1/rad] (both 0 where the joint has no state)."""
        zero = jnp.zeros_like(v)
        return zero, zero

    # --- the whole law: linearisation and identification ---------------------------------

    @abc.abstractmethod
    def without_coulomb(self):
        """The law's linear part (its viscous friction): the loop ``crlb`` linearises, which
        IMBIC promises to leave. Traceable (no checks)."""

    @abc.abstractmethod
    def has_coulomb(self) -> bool:
        """Whether the law has a nonlinear (Coulomb, Stribeck) part (concrete values)."""

    def to_internal(self, names) -> dict:
        """The optimiser's values ``{name: (2,)}`` of the free parameters ``names`` (concrete,
        NumPy): the log of each by default. A ``ValueError`` where a value cannot be
        represented (a value <= 0 has no logarithm)."""
        out = {}
        for name in names:
            v = np.asarray(getattr(self, name), dtype=float)
            if np.any(v <= 0):
                raise ValueError(
                    f"identify: friction.{name} must start > 0 to be estimated (on a log scale), got {v.tolist()}"
                )
            out[name] = np.log(v)
        return out

    def from_internal(self, raw: dict) -> dict:
        """Inverse of ``to_internal``, traceable: ``{name: value}`` of the free parameters."""
        return {name: jnp.exp(q) for name, q in raw.items()}


def friction_kind(name: str, *, where: str = ""):
    """The friction class registered as ``name`` (one line naming the known kinds if none)."""
    return FRICTION_KINDS.get(name, where=where)
