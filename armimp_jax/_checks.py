"""Input validation shared by the public entry points: x64, choices, shapes, values.

A value check sees concrete values at once and raises a one-line ``ValueError`` naming the
value and the allowed range. A traced value (a parameter built inside ``jit``, ``vmap`` or
``grad``) cannot be inspected then, so the same rule is attached to it with
``equinox.error_if``: the check runs when the compiled program runs, and a violation raises
there with the same message (raised by equinox as a runtime error of the computation;
under ``vmap`` one bad lane fails the call, as a concrete bad value would). Gradients pass
through the checks unchanged. What is checked where: docs/design.md.
"""

from __future__ import annotations

import warnings

import equinox as eqx
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


# Every deprecated name or keyword warns through ``deprecated`` and goes in this version;
# docs/CHANGELOG.md says what replaces each.
DEPRECATIONS_END = "3.0"


def deprecated(what: str, instead: str) -> None:
    """Warn that ``what`` is deprecated (a ``DeprecationWarning`` at the caller's caller, the
    user's line) and goes in ``DEPRECATIONS_END``; ``instead`` says what replaces it."""
    message = f"{what} is deprecated and goes in armimp_jax {DEPRECATIONS_END}: {instead}"
    warnings.warn(message, DeprecationWarning, stacklevel=3)


def check_choice(name: str, value, allowed) -> None:
    if isinstance(value, bool) or value not in allowed:
        raise ValueError(f"unknown {name} {value!r}; allowed: {', '.join(map(repr, allowed))}")


def check_int(name: str, value, *, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    if value < minimum:
        raise ValueError(f"{name} must be >= {minimum}, got {value}")
    return int(value)


def check_key(key, *, where: str) -> None:
    """A ``jax.random`` key: a typed key (``jax.random.key(seed)``) or a raw ``(2,)`` uint32
    one (``jax.random.PRNGKey(seed)``); a one-line error naming what was given otherwise."""
    dtype = getattr(key, "dtype", None)
    if dtype is not None and jnp.issubdtype(dtype, jax.dtypes.prng_key):
        return
    if dtype == jnp.uint32 and getattr(key, "shape", None) == (2,):
        return
    raise ValueError(
        f"{where}: key must be a jax.random key (e.g. jax.random.key(0)), got {type(key).__name__} {key!r}"
    )


def is_concrete(x) -> bool:
    """True when every leaf of ``x`` holds values to inspect (no tracer under jit/grad/vmap)."""
    return not any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree.leaves(x))


def _traced_rule(x, bad, message: str):
    """``x`` with the rule "not ``bad``" attached (checked when the program runs)."""
    return eqx.error_if(x, bad, message)


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


def _show(a) -> str:
    a = np.asarray(a)
    return repr(a.item()) if a.ndim == 0 else repr(a.tolist())


def as_param(name: str, x, shape: tuple[int, ...], *, where: str, broadcast: bool = False):
    """A float64 parameter of ``shape`` (a scalar broadcast to it when ``broadcast``), finite
    (checked at once when concrete, when the program runs when traced)."""
    if isinstance(x, (jax.Array, jax.core.Tracer)):
        arr = as_float64(name, x, where=where)
        if broadcast and arr.shape == ():
            arr = jnp.broadcast_to(arr, shape)
    else:  # host values stay NumPy: building parameters starts no JAX backend
        try:
            arr = np.asarray(x, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError(f"{where}: {name} must be numeric, got {x!r}") from None
        if broadcast and arr.shape == ():
            arr = np.broadcast_to(arr, shape).copy()
    if arr.shape != shape:
        allowed = f"a scalar or shape {shape}" if broadcast else f"shape {shape}"
        raise ValueError(f"{where}: {name} must be {allowed}, got shape {arr.shape}")
    if not is_concrete(arr):
        return _traced_rule(arr, ~jnp.all(jnp.isfinite(arr)), f"{where}: {name} must be finite")
    if not np.all(np.isfinite(np.asarray(arr))):
        raise ValueError(f"{where}: {name} must be finite, got {_show(arr)}")
    return arr


def check_range(name: str, x, *, where: str, minimum: float, exclusive: bool = False, unit: str = ""):
    """``x``, refused when below ``minimum`` (or at it, when ``exclusive``)."""
    op = ">" if exclusive else ">="
    if not is_concrete(x):
        bad = jnp.any(x <= minimum) if exclusive else jnp.any(x < minimum)
        return _traced_rule(x, bad, f"{where}: {name} must be {op} {minimum:g}{unit}")
    a = np.asarray(x)
    if np.any(a <= minimum if exclusive else a < minimum):
        raise ValueError(f"{where}: {name} must be {op} {minimum:g}{unit}, got {_show(a)}")
    return x


def check_positive_definite(name: str, a, *, where: str, unit: str = ""):
    """``a`` (2x2), refused when its symmetric part is not positive definite."""
    if not is_concrete(a):
        # A symmetric 2x2 is positive definite iff its (1, 1) entry and its determinant are > 0.
        s12 = 0.5 * (a[..., 0, 1] + a[..., 1, 0])
        bad = jnp.any(a[..., 0, 0] <= 0) | jnp.any(a[..., 0, 0] * a[..., 1, 1] - s12 * s12 <= 0)
        message = f"{where}: {name} must have a positive definite symmetric part (eigenvalues of (A + A^T)/2 > 0)"
        return _traced_rule(a, bad, message + unit)
    m = np.asarray(a)
    eig = np.linalg.eigvalsh(0.5 * (m + m.T))
    if not np.all(eig > 0.0):
        raise ValueError(
            f"{where}: {name} must have a positive definite symmetric part (eigenvalues of (A + A^T)/2 > 0)"
            f"{unit}; got {m.tolist()} with eigenvalues {eig.tolist()}"
        )
    return a


def check_positive_semidefinite(name: str, a, *, where: str, unit: str = ""):
    """``a`` (2x2), refused when its symmetric part has a negative eigenvalue."""
    message = f"{where}: {name} must have a positive semi-definite symmetric part (eigenvalues of (A + A^T)/2 >= 0)"
    if not is_concrete(a):
        s12 = 0.5 * (a[..., 0, 1] + a[..., 1, 0])
        bad = jnp.any(a[..., 0, 0] < 0) | jnp.any(a[..., 1, 1] < 0) | jnp.any(a[..., 0, 0] * a[..., 1, 1] < s12 * s12)
        return _traced_rule(a, bad, message + unit)
    m = np.asarray(a)
    eig = np.linalg.eigvalsh(0.5 * (m + m.T))
    if not np.all(eig >= -1e-12 * max(1.0, np.abs(m).max())):
        raise ValueError(f"{message}{unit}; got {m.tolist()} with eigenvalues {eig.tolist()}")
    return a
