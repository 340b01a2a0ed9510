"""The controller as an extension point: ``AbstractController``, whose methods are everything
the simulation loop, the linearisation behind ``crlb``, identification and experiment design
ask of a controller, and the registry of its kinds.

- ``bind(robot, q0, x0, period=)``: the controller with its defaults resolved for the trial's
  equilibrium and control period (IMBIC's desired inertia ``M_x(q0)``, an admittance's
  discretised virtual model); ``make_trial`` calls it.
- ``check_loop(trial)``: refuse a trial whose loop with the arm this controller makes unstable
  (by default nothing; ``make_trial`` calls it after ``bind``).
- ``init(x0)``: its memory at rest at ``x0`` (a pytree of floats: the linearisation treats
  every float of it as loop state).
- ``step(memory, x, xd, fh, f_delta, x0, period, path=None)``: the Cartesian command ``F_u,k`` [N]
  ``(2,)`` held over the next period (the motors apply ``J^T F_u``), and the new memory, from the
  measured ``x_k`` [m], ``xd_k`` [m/s], ``F_h,k`` [N] (the force on the hand) and the
  perturbation ``F_Delta,k`` [N]. ``path`` is ``None`` for a still arm; for a moving one
  (docs/model.md, "The arm during a movement") it is ``(offset, velocity)``, the planned set
  point at ``t_k`` as ``x_d,k - x0`` [m] and ``xd_e(t_k)`` [m/s] ``(2,)`` each: the controller
  holds ``x_d,k`` where it held ``x0`` and damps ``xd_k - xd_e(t_k)`` where it damped ``xd_k``.
  A kind whose ``step`` also takes ``joints`` receives the loop's measured joint state,
  ``Joints(q, qd, robot)``: the encoders' angles ``q_k`` [rad] and rates ``qd_k`` [rad/s] ``(2,)``
  as the sensors read them, and the trial's ``Robot`` (for ``aj.linear.jacobian(q, robot)``), so
  a joint-space law needs no inverse kinematics of its own.

The linearised loop is the forward-mode derivative of the simulation's own period step
(``_identification/linear.py``), so a kind needs no linear form of its own. Experiment design
moves the two gains named by ``DESIGN_GAINS`` (stiffness [N/m], damping [N s/m]) through
``with_gains``. A new controller is one class in one file (docs/extending.md).
"""

from __future__ import annotations

import abc
import functools
import inspect
from typing import Any, ClassVar, NamedTuple

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ..._checks import as_param, check_positive_definite, check_positive_semidefinite
from ..._pytree import replace_unchecked, show_fields
from .. import kinds

CONTROLLER_KINDS = kinds.Registry("controller")


class Joints(NamedTuple):
    """The measured joint state a controller's ``step`` receives when it takes ``joints``: the
    angles ``q`` [rad] and rates ``qd`` [rad/s], ``(2,)`` each, as the encoders (and the rate
    sensors' noise) give them, and the trial's ``robot``."""

    q: Any
    qd: Any
    robot: Any


def step_takes(controller, argument: str) -> bool:
    """Whether a controller's ``step`` takes the optional ``argument`` (``"path"``: the planned set
    point; ``"joints"``: the measured joint state)."""
    return argument in inspect.signature(type(controller).step).parameters


def reads_joints(controller) -> bool:
    """Whether a controller's ``step`` takes the measured joint state (a ``joints`` argument)."""
    return step_takes(controller, "joints")


def matvec(a, v):
    """``a @ v`` for a ``(2, 2)`` matrix and a ``(2,)`` vector, with a fixed summation order
    (the rounding stays identical in batched and unbatched programs)."""
    return jnp.stack([a[0, 0] * v[0] + a[0, 1] * v[1], a[1, 0] * v[0] + a[1, 1] * v[1]])


def _gain_value(value, *, where, name, unit, optional, semidefinite):
    if value is None and optional:
        return None
    unit = "" if unit is None else f" [{unit}]"
    arr = as_param(f"{name}{unit}", value, (2, 2), where=where)
    if semidefinite:
        return check_positive_semidefinite(name, arr, where=where, unit=unit)
    return check_positive_definite(name, arr, where=where, unit=unit)


def gain_field(default, *, semidefinite: bool = False):
    """A controller's ``(2, 2)`` gain field: float64, finite, with a positive definite symmetric
    part (positive semi-definite when ``semidefinite``), checked as ``per_joint`` checks (a
    one-line ``ValueError`` naming the kind, the field and its unit when concrete, the rule
    carried into the program when traced). A ``None`` default makes ``None`` a value (one the
    kind resolves itself)."""
    check = functools.partial(_gain_value, optional=default is None, semidefinite=semidefinite)
    return eqx.field(converter=kinds.Converter(check, where="gain", name="a gain"), default=default)


class AbstractController(eqx.Module):
    """A controller: an immutable pytree of gains (``(2, 2)`` float leaves) with the methods above.

    Class attributes of a kind: ``kind`` (its name in configs, points and records), ``UNITS``
    (every parameter's unit, or a tuple of allowed words for a text option), ``DESIGN_GAINS``
    (the ``(stiffness, damping)`` parameters experiment design may move, or ``None``) and
    ``RECORDED`` (the parameters a record writes; ``None``: all).
    """

    kind: ClassVar[str]
    UNITS: ClassVar[dict]
    DESIGN_GAINS: ClassVar[tuple[str, str] | None] = None
    RECORDED: ClassVar[tuple[str, ...] | None] = None

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        kinds.name_fields(cls)
        if "UNITS" in cls.__dict__:
            kinds.check_units(cls)
        CONTROLLER_KINDS.register(cls)

    __repr__ = show_fields

    # --- what the simulation loop calls -------------------------------------------------

    def bind(self, robot, q0, x0, *, period: float):
        """The controller resolved for the equilibrium ``q0`` [rad] / ``x0`` [m] and the control
        ``period`` [s] (by default itself)."""
        return self

    @abc.abstractmethod
    def init(self, x0):
        """The memory at rest at ``x0`` [m]."""

    @abc.abstractmethod
    def step(self, memory, x, xd, fh, f_delta, x0, period, path=None):
        """``(F_u,k, new memory)`` from the measured samples and, for a moving arm, the planned
        set point ``path`` (module docstring). A kind whose ``step`` takes no ``path`` serves
        still arms only (``make_trial`` refuses it a moving one)."""

    def check_loop(self, trial) -> None:
        """Refuse, in one line, a ``trial`` (``make_trial``'s, holding this bound controller) whose
        loop with the arm on the handle this controller makes unstable; called with concrete
        values. By default nothing is checked (``simulate`` flags a trial that diverges)."""

    # --- what experiment design calls ----------------------------------------------------

    def with_gains(self, **values):
        """The bound controller with some parameters replaced (traceable: design differentiates
        through it); a kind with derived values re-derives them."""
        return replace_unchecked(self, **values)

    # --- the schema: configs, sweep points, records --------------------------------------

    @classmethod
    def parameters(cls) -> dict:
        """``{name: kinds.Parameter}`` of the controller's parameters (gains ``(2, 2)``)."""
        return kinds.parameters(cls, (2, 2))

    def record(self) -> dict:
        """The controller as ``design.json`` writes it: ``{"type": kind, name: 2x2 list}`` of the
        ``RECORDED`` parameters (all by default)."""
        return kinds.record(self, self.RECORDED or self.parameters())

    def settings(self) -> dict:
        """Every parameter given (``None`` ones left out), as a config's ``[controller]`` takes them."""
        return kinds.record(self, self.parameters())

    @classmethod
    def point_parameters(cls) -> dict:
        """``{name: (default, unit)}`` of the controller's settings in a sweep point (a number
        is that times the identity); by default every gain with a numeric default."""
        out = {}
        for p in cls.parameters().values():
            if p.shape is not None and p.default is not None and p.default is not kinds.REQUIRED:
                d = np.asarray(p.default, dtype=float)
                out[p.name] = (float(d[0, 0]) if np.array_equal(d, d[0, 0] * np.eye(2)) else d.tolist(), p.unit)
        return out

    @classmethod
    def from_point(cls, values: dict):
        """The controller of a sweep point's settings (``point_parameters``' names)."""
        return cls(**{k: v * np.eye(2) if np.ndim(v) == 0 else v for k, v in values.items()})


def controller_kind(name: str, *, where: str = ""):
    """The controller class registered as ``name`` (one line naming the known kinds if none)."""
    return CONTROLLER_KINDS.get(name, where=where)
