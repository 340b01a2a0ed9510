"""Input validation shared by the public entry points: x64, choices, shapes, concreteness."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np


def require_x64(where: str) -> None:
    """Raise if float64 is off: the physics (stiff LuGre bristles, 1e-5 s steps) needs it."""
    if not jax.config.jax_enable_x64:
        raise ValueError(
            f"{where} needs float64, but jax_enable_x64 is off (arrays would be float32). "
            'Call jax.config.update("jax_enable_x64", True) at program start.'
        )


def check_choice(name: str, value, allowed) -> None:
    if isinstance(value, bool) or value not in allowed:
        raise ValueError(f"unknown {name} {value!r}; allowed: {', '.join(map(repr, allowed))}")


def check_int(name: str, value, *, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    if value < minimum:
        raise ValueError(f"{name} must be >= {minimum}, got {value}")
    return int(value)


def is_concrete(x) -> bool:
    """True when ``x`` has values we can inspect now (not a tracer under jit/grad/vmap)."""
    return not any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree.leaves(x))


def as_float64(name: str, x, shape: tuple[int, ...] | None = None, *, where: str):
    """Convert to a float64 array (keeping tracers), checking shape and refusing float32."""
    require_x64(where)
    arr = jnp.asarray(x)
    if arr.dtype != jnp.float64:
        if jnp.issubdtype(arr.dtype, jnp.floating) or not jnp.issubdtype(arr.dtype, jnp.number):
            raise ValueError(f"{name} must be float64, got dtype {arr.dtype}")
        arr = arr.astype(jnp.float64)
    if shape is not None and arr.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {arr.shape}")
    return arr
