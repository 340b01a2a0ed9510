"""Which parameters of a trial are estimated, and the vector an optimiser moves.

A free parameter is named by its path in the trial (``"arm.stiffness"``, ``"friction.tau_c"``).
The optimiser works on one flat vector ``p``: the arm's matrices by their entries (all four,
or three when constrained symmetric: ``[a11, a12 = a21, a22]``), the friction parameters per
joint on log scales (they are positive, and their scales span orders of magnitude), with
stiction kept above the Coulomb torque as ``LuGre`` requires: ``tau_s = tau_c + exp(b)``;
``tau_c = exp(a)``, or ``tau_s sigmoid(a)`` when ``tau_s`` is held fixed. An optimiser
left free to cross ``tau_s < tau_c`` was seen to dive there from a generic start (a
Stribeck curve that rises with speed), where the fit is rough and meaningless.
The *natural* vector lists every entry in the parameter's own units and shape, row by row
(a symmetric matrix keeps both off-diagonal entries); covariances are reported on it.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .._pytree import replace_unchecked
from .._simulate import Trial

ARM_PARAMETERS = {"arm.mass": "kg", "arm.damping": "N s/m", "arm.stiffness": "N/m"}
FRICTION_PARAMETERS = {
    "friction.tau_c": "N m",
    "friction.tau_s": "N m",
    "friction.sigma0": "N m/rad",
    "friction.sigma1": "N m s/rad",
    "friction.sigma2": "N m s/rad",
}
PARAMETERS = {**ARM_PARAMETERS, **FRICTION_PARAMETERS}  # name -> unit


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


def make_layout(free, symmetric=()) -> Layout:
    """Check the names of ``free`` and ``symmetric`` (one-line errors listing the valid names)."""
    if isinstance(free, str):
        free = (free,)
    free = tuple(free)
    valid = ", ".join(PARAMETERS)
    if not free:
        raise ValueError(f"identify: free must name at least one parameter; valid names: {valid}")
    for name in free:
        if name not in PARAMETERS:
            raise ValueError(f"identify: unknown parameter {name!r}; valid names: {valid}")
    if len(set(free)) != len(free):
        raise ValueError(f"identify: free names a parameter twice: {list(free)}")
    symmetric = (symmetric,) if isinstance(symmetric, str) else tuple(symmetric)
    for name in symmetric:
        if name not in free or name not in ARM_PARAMETERS:
            raise ValueError(
                f"identify: symmetric names {name!r}, which is not a free arm matrix; free arm matrices: "
                f"{[n for n in free if n in ARM_PARAMETERS]}"
            )
    return Layout(free, tuple(n in symmetric for n in free))


def _get(trial: Trial, name: str):
    group, field = name.split(".")
    return getattr(getattr(trial, group), field)


def pack(layout: Layout, trial: Trial):
    """``p`` of a trial's values (concrete); a ``ValueError`` where a value cannot be represented
    (a friction value <= 0 has no logarithm; a symmetric matrix must start symmetric)."""
    parts = []
    for name, sym in zip(layout.names, layout.symmetric, strict=True):
        v = np.asarray(_get(trial, name), dtype=float)
        if name in ARM_PARAMETERS:
            if sym:
                if abs(v[0, 1] - v[1, 0]) > 1e-12 * max(1.0, np.abs(v).max()):
                    raise ValueError(f"identify: {name} is constrained symmetric but starts at {v.tolist()}")
                parts.append(np.array([v[0, 0], v[0, 1], v[1, 1]]))
            else:
                parts.append(v.reshape(-1))
        elif name == "friction.tau_s":
            excess = v - np.asarray(trial.friction.tau_c, dtype=float)
            if np.any(excess <= 0):
                raise ValueError(
                    f"identify: friction.tau_s must start above tau_c to be estimated (tau_s = tau_c + exp(b)), got "
                    f"tau_s = {v.tolist()} and tau_c = {np.asarray(trial.friction.tau_c).tolist()} N m"
                )
            parts.append(np.log(excess))
        elif name == "friction.tau_c" and "friction.tau_s" not in layout.names:
            ratio = v / np.asarray(trial.friction.tau_s, dtype=float)
            if np.any(v <= 0) or np.any(ratio >= 1):
                raise ValueError(
                    f"identify: friction.tau_c must start in (0, tau_s) to be estimated with tau_s held fixed, got "
                    f"tau_c = {v.tolist()} and tau_s = {np.asarray(trial.friction.tau_s).tolist()} N m"
                )
            parts.append(np.log(ratio / (1.0 - ratio)))
        else:
            if np.any(v <= 0):
                raise ValueError(f"identify: {name} must start > 0 to be estimated (on a log scale), got {v.tolist()}")
            parts.append(np.log(v))
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
    supplies the fixed friction torque that a free one is tied to."""
    out, raw, i = {}, {}, 0
    for k, name in enumerate(layout.names):
        n = layout.n_internal(k)
        raw[name] = p[i : i + n]
        i += n
    for k, (name, sym) in enumerate(zip(layout.names, layout.symmetric, strict=True)):
        q = raw[name]
        if name in ARM_PARAMETERS:
            out[name] = jnp.stack([q[0], q[1], q[1], q[2]]).reshape(2, 2) if sym else q.reshape(2, 2)
        elif name not in ("friction.tau_c", "friction.tau_s"):
            out[name] = jnp.exp(q)
    if "friction.tau_s" in raw:
        tau_c = jnp.exp(raw["friction.tau_c"]) if "friction.tau_c" in raw else trial.friction.tau_c
        if "friction.tau_c" in raw:
            out["friction.tau_c"] = tau_c
        out["friction.tau_s"] = tau_c + jnp.exp(raw["friction.tau_s"])
    elif "friction.tau_c" in raw:
        out["friction.tau_c"] = trial.friction.tau_s * jax.nn.sigmoid(raw["friction.tau_c"])
    return out


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
    friction = {n.split(".")[1]: v for n, v in values.items() if n in FRICTION_PARAMETERS}
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
