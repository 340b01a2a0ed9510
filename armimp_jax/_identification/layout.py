"""Which parameters of a trial are estimated, and the vector an optimiser moves.

A free parameter is named by its path in the trial (``"arm.stiffness"``, ``"friction.tau_c"``).
The optimiser works on one flat vector ``p``: the arm's matrices by their entries (all four,
or three when constrained symmetric: ``[a11, a12 = a21, a22]``), the friction law's parameters
per joint on the law's own internal scales (``AbstractFriction.to_internal`` /
``from_internal``: logs by default, as they are positive and span orders of magnitude;
LuGre keeps its stiction above the Coulomb torque). Which friction parameters may be freed is
the law's ``IDENTIFIABLE``. The *natural* vector lists every entry in the parameter's own
units and shape, row by row (a symmetric matrix keeps both off-diagonal entries);
covariances are reported on it.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .._model.friction import FRICTION_KINDS
from .._pytree import replace_unchecked
from .._simulate import Trial

ARM_PARAMETERS = {"arm.mass": "kg", "arm.damping": "N s/m", "arm.stiffness": "N/m"}


def friction_parameters(friction=None) -> dict:
    """``{"friction.<name>": unit}`` of the parameters a friction law (an instance or class) lets
    ``identify`` free; ``None``: those of every registered law."""
    laws = [friction] if friction is not None else [FRICTION_KINDS.get(n) for n in FRICTION_KINDS.names()]
    out = {}
    for law in laws:
        out.update({f"friction.{n}": law.UNITS[n] for n in law.IDENTIFIABLE})
    return out


def parameter_units(friction=None) -> dict:
    """``{name: unit}`` of every parameter that may be freed: the arm's matrices, then the
    friction law's (``friction_parameters``)."""
    return {**ARM_PARAMETERS, **friction_parameters(friction)}


class Layout(NamedTuple):
    """The free parameters (static and hashable): their names in order, and which arm matrices
    are constrained symmetric."""

    names: tuple[str, ...]
    symmetric: tuple[bool, ...]

    def shape(self, name: str) -> tuple[int, ...]:
        return (2, 2) if name in ARM_PARAMETERS else (2,)

    def n_internal(self, i: int) -> int:
        return 3 if self.symmetric[i] else (4 if self.names[i] in ARM_PARAMETERS else 2)

    @property
    def size(self) -> int:
        """Length of ``p``."""
        return sum(self.n_internal(i) for i in range(len(self.names)))

    def labels(self) -> list[str]:
        """Names of the natural vector's entries, e.g. ``"arm.mass[0,1]"``, ``"friction.tau_c[1]"``."""
        out = []
        for name in self.names:
            if name in ARM_PARAMETERS:
                out += [f"{name}[{i},{j}]" for i in range(2) for j in range(2)]
            else:
                out += [f"{name}[{i}]" for i in range(2)]
        return out

    def friction_names(self) -> tuple[str, ...]:
        """The free friction law's fields, in order (``"tau_c"`` for ``"friction.tau_c"``)."""
        return tuple(n.split(".", 1)[1] for n in self.names if n not in ARM_PARAMETERS)


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


def pack_arm(layout: Layout, trial: Trial):
    """``p`` of a layout of arm matrices only, traceable (no checks: a symmetric matrix is read
    from its upper triangle)."""
    parts = []
    for name, sym in zip(layout.names, layout.symmetric, strict=True):
        if name not in ARM_PARAMETERS:
            raise ValueError(f"pack_arm: {name} is not an arm matrix")
        v = jnp.asarray(_get(trial, name))
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
    arm = {n.split(".")[1]: v for n, v in values.items() if n in ARM_PARAMETERS}
    friction = {n.split(".")[1]: v for n, v in values.items() if n not in ARM_PARAMETERS}
    out = trial
    if arm:
        out = replace_unchecked(out, arm=replace_unchecked(out.arm, **arm))
    if friction:
        out = replace_unchecked(out, friction=replace_unchecked(out.friction, **friction))
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
