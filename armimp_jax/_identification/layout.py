"""Which parameters of a trial are estimated, and the vector an optimiser moves.

A free parameter is named by its path in the trial (``"arm.stiffness"``, ``"friction.tau_c"``,
``"robot.inertia"``, ``"sensors.force_gain"``). The optimiser works on one flat vector ``p``:
the arm's matrices by their entries (all four, or three when constrained symmetric: ``[a11,
a12 = a21, a22]``); the friction law's parameters per joint on the law's own internal scales
(``AbstractFriction.to_internal`` / ``from_internal``: logs by default, as they are positive
and span orders of magnitude; LuGre keeps its stiction above the Coulomb torque; which may be
freed is the law's ``IDENTIFIABLE``); the robot's and the force channel's calibration
(``ROBOT_PARAMETERS``, ``SENSOR_PARAMETERS``) on the scales of ``_CALIBRATION``: the link
inertias ``(c1, c2, c3)`` and the force gain on log scales (positive), the force offset as it
is, the force delay in control periods (the simulation holds it within its delay line). The
*natural* vector lists every entry in the parameter's own units and shape, row by row (a
symmetric matrix keeps both off-diagonal entries); covariances are reported on it. The arm's,
the robot's and the sensors' parameters are those of the linearised loop (``LINEAR``): the
efficient statistic covers them; the friction's are nuisances matched by their own statistics.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .._model.friction import FRICTION_KINDS
from .._model.sensors import IDENTIFIABLE as SENSOR_IDENTIFIABLE
from .._pytree import replace_unchecked
from .._simulate import Trial

ARM_PARAMETERS = {"arm.mass": "kg", "arm.damping": "N s/m", "arm.stiffness": "N/m"}
ROBOT_PARAMETERS = {"robot.inertia": "kg m^2"}
SENSOR_PARAMETERS = {f"sensors.{name}": unit for name, (unit, _, _) in SENSOR_IDENTIFIABLE.items()}
# The calibration parameters' shapes and internal scales ("log": positive; "plain": as they
# are; "periods": the value over the control period); the sensors' from their schema
_CALIBRATION = {
    "robot.inertia": ((3,), "log"),
    **{f"sensors.{name}": (shape, scale) for name, (_, shape, scale) in SENSOR_IDENTIFIABLE.items()},
}
# The parameters of the linearised loop: what the efficient statistic (and crlb) covers.
LINEAR = {**ARM_PARAMETERS, **ROBOT_PARAMETERS, **SENSOR_PARAMETERS}


def friction_parameters(friction=None) -> dict:
    """``{"friction.<name>": unit}`` of the parameters a friction law (an instance or class) lets
    ``identify`` free; ``None``: those of every registered law."""
    laws = [friction] if friction is not None else [FRICTION_KINDS.get(n) for n in FRICTION_KINDS.names()]
    out = {}
    for law in laws:
        out.update({f"friction.{n}": law.UNITS[n] for n in law.IDENTIFIABLE})
    return out


def parameter_units(friction=None) -> dict:
    """``{name: unit}`` of every parameter that may be freed: the arm's matrices, the friction
    law's (``friction_parameters``), the robot's and the force channel's."""
    return {**ARM_PARAMETERS, **friction_parameters(friction), **ROBOT_PARAMETERS, **SENSOR_PARAMETERS}


class Layout(NamedTuple):
    """The free parameters (static and hashable): their names in order, and which arm matrices
    are constrained symmetric."""

    names: tuple[str, ...]
    symmetric: tuple[bool, ...]

    def shape(self, name: str) -> tuple[int, ...]:
        if name in _CALIBRATION:
            return _CALIBRATION[name][0]
        return (2, 2) if name in ARM_PARAMETERS else (2,)

    def n_internal(self, i: int) -> int:
        return 3 if self.symmetric[i] else int(np.prod(self.shape(self.names[i]), dtype=int))

    @property
    def size(self) -> int:
        """Length of ``p``."""
        return sum(self.n_internal(i) for i in range(len(self.names)))

    def labels(self) -> list[str]:
        """Names of the natural vector's entries, e.g. ``"arm.mass[0,1]"``, ``"friction.tau_c[1]"``."""
        out = []
        for name in self.names:
            shape = self.shape(name)
            if not shape:
                out.append(name)
            else:
                out += [f"{name}[{','.join(map(str, i))}]" for i in np.ndindex(*shape)]
        return out

    def friction_names(self) -> tuple[str, ...]:
        """The free friction law's fields, in order (``"tau_c"`` for ``"friction.tau_c"``)."""
        return tuple(n.split(".", 1)[1] for n in self.names if n.startswith("friction."))

    def linear(self) -> Layout | None:
        """The layout of the linearised loop's parameters alone (``None`` when none is free)."""
        kept = [(n, s) for n, s in zip(self.names, self.symmetric, strict=True) if n in LINEAR]
        return Layout(tuple(n for n, _ in kept), tuple(s for _, s in kept)) if kept else None

    def index(self, names) -> np.ndarray:
        """Positions in ``p`` of the internal entries of the parameters in ``names``."""
        out, i = [], 0
        for k, name in enumerate(self.names):
            n = self.n_internal(k)
            if name in names:
                out += list(range(i, i + n))
            i += n
        return np.asarray(out, dtype=int)


def make_layout(free, symmetric=(), *, friction=None, where: str = "identify") -> Layout:
    """Check the names of ``free`` and ``symmetric`` (one-line errors listing the valid names).
    ``friction`` (the trial's law, an instance or class) says which friction parameters may be
    freed; ``None`` allows those of every registered law."""
    if isinstance(free, str):
        free = (free,)
    free = tuple(free)
    valid = parameter_units(friction)
    names = ", ".join(valid)
    if not free:
        raise ValueError(f"{where}: free must name at least one parameter; valid names: {names}")
    for name in free:
        if name not in valid:
            law = "" if friction is None else f" (the friction's those of {getattr(friction, 'kind', '')!r})"
            raise ValueError(f"{where}: unknown parameter {name!r}; valid names: {names}{law}")
    if len(set(free)) != len(free):
        raise ValueError(f"{where}: free names a parameter twice: {list(free)}")
    symmetric = (symmetric,) if isinstance(symmetric, str) else tuple(symmetric)
    for name in symmetric:
        if name not in free or name not in ARM_PARAMETERS:
            raise ValueError(
                f"{where}: symmetric names {name!r}, which is not a free arm matrix; free arm matrices: "
                f"{[n for n in free if n in ARM_PARAMETERS]}"
            )
    return Layout(free, tuple(n in symmetric for n in free))


def _get(trial: Trial, name: str):
    group, field = name.split(".")
    return getattr(getattr(trial, group), field)


def pack(layout: Layout, trial: Trial):
    """``p`` of a trial's values (concrete); a ``ValueError`` where a value cannot be represented
    (a friction value outside its law's internal scale; a symmetric matrix must start symmetric)."""
    friction = dict(trial.friction.to_internal(layout.friction_names())) if layout.friction_names() else {}
    parts = []
    for name, sym in zip(layout.names, layout.symmetric, strict=True):
        if name in _CALIBRATION:
            parts.append(_calibration_internal(name, np.asarray(_get(trial, name), dtype=float), trial.period))
            continue
        if name not in ARM_PARAMETERS:
            parts.append(np.asarray(friction[name.split(".", 1)[1]], dtype=float))
            continue
        v = np.asarray(_get(trial, name), dtype=float)
        if sym:
            if abs(v[0, 1] - v[1, 0]) > 1e-12 * max(1.0, np.abs(v).max()):
                raise ValueError(f"identify: {name} is constrained symmetric but starts at {v.tolist()}")
            parts.append(np.array([v[0, 0], v[0, 1], v[1, 1]]))
        else:
            parts.append(v.reshape(-1))
    return jnp.asarray(np.concatenate(parts))


def _calibration_internal(name: str, v, period: float):
    """A calibration parameter's internal values (concrete), with one-line errors."""
    scale = _CALIBRATION[name][1]
    if scale == "log":
        if np.any(v <= 0):
            raise ValueError(f"identify: {name} must start > 0 to be estimated (on a log scale), got {v.tolist()}")
        return np.log(v).reshape(-1)
    return (v / period if scale == "periods" else v).reshape(-1)


def _calibration_value(name: str, q, period: float):
    """Inverse of ``_calibration_internal``, traceable."""
    scale = _CALIBRATION[name][1]
    q = q.reshape(_CALIBRATION[name][0])
    return jnp.exp(q) if scale == "log" else (q * period if scale == "periods" else q)


def pack_arm(layout: Layout, trial: Trial):
    """``p`` of a layout of the linearised loop's parameters (``LINEAR``: the arm's matrices, the
    robot's and the force channel's calibration), traceable (no checks: a symmetric matrix is
    read from its upper triangle)."""
    parts = []
    for name, sym in zip(layout.names, layout.symmetric, strict=True):
        if name not in LINEAR:
            raise ValueError(f"pack_arm: {name} is not a parameter of the linearised loop")
        v = jnp.asarray(_get(trial, name))
        if name in _CALIBRATION:
            scale = _CALIBRATION[name][1]
            v = jnp.log(v) if scale == "log" else (v / trial.period if scale == "periods" else v)
            parts.append(v.reshape(-1))
        else:
            parts.append(jnp.stack([v[0, 0], v[0, 1], v[1, 1]]) if sym else v.reshape(-1))
    return jnp.concatenate(parts)


def split(layout: Layout, p, trial: Trial) -> dict:
    """``p`` -> ``{name: value}`` in the parameters' units and shapes (traceable); ``trial``
    supplies the friction law that maps its internal values (and the fixed values a free one
    is tied to)."""
    out, raw, i = {}, {}, 0
    for k, (name, sym) in enumerate(zip(layout.names, layout.symmetric, strict=True)):
        n = layout.n_internal(k)
        q = p[i : i + n]
        i += n
        if name in ARM_PARAMETERS:
            out[name] = jnp.stack([q[0], q[1], q[1], q[2]]).reshape(2, 2) if sym else q.reshape(2, 2)
        elif name in _CALIBRATION:
            out[name] = _calibration_value(name, q, trial.period)
        else:
            raw[name.split(".", 1)[1]] = q
    if raw:
        values = trial.friction.from_internal(raw)
        out.update({f"friction.{n}": values[n] for n in raw})
    return {name: out[name] for name in layout.names}


def natural(layout: Layout, p, trial: Trial):
    """The natural vector (every entry of every free parameter, in its units) of ``p``."""
    values = split(layout, p, trial)
    return jnp.concatenate([values[n].reshape(-1) for n in layout.names])


def natural_jacobian(layout: Layout, p, trial: Trial):
    """``d natural / d p`` ``(n_natural, n_p)``: maps a covariance of ``p`` to natural units."""
    return jax.jacfwd(lambda q: natural(layout, q, trial))(p)


@functools.partial(jax.jit, static_argnums=0)
def natural_with_jacobian(layout: Layout, p, trial: Trial):
    """``(natural(p), natural_jacobian(p))`` as one compiled program, for host code (op by op,
    each operation of the pair would compile on its own)."""
    return natural(layout, p, trial), natural_jacobian(layout, p, trial)


def with_values(layout: Layout, trial: Trial, p) -> Trial:
    """``trial`` with its free parameters set from ``p`` (no checks: traced values pass, and an
    optimiser may try values the constructors would refuse)."""
    values = split(layout, p, trial)
    out = trial
    for group in ("arm", "friction", "robot", "sensors"):
        fields = {n.split(".")[1]: v for n, v in values.items() if n.split(".")[0] == group}
        if group == "sensors" and fields:
            fields["calibrated"] = True  # the recorded force channel's calibration is then simulated
        if fields:
            out = replace_unchecked(out, **{group: replace_unchecked(getattr(out, group), **fields)})
    return out


def unflatten(layout: Layout, flat) -> dict:
    """A natural vector -> ``{name: array in the parameter's shape}``, of the vector's own
    array type (NumPy, or JAX and traceable)."""
    out, i = {}, 0
    for name in layout.names:
        shape = layout.shape(name)
        n = int(np.prod(shape))
        out[name] = flat[i : i + n].reshape(shape)
        i += n
    return out
