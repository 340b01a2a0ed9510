"""Immutable parameter pytrees whose constructor validates, and whose unflattening does not.

``@params(static=(...))`` turns a class into a frozen dataclass registered as a pytree:
every field not named in ``static`` is a leaf (a float array that ``jax.vmap`` and
``jax.grad`` see), static fields go into the tree structure (hashable, fixed per
compilation). Users call the constructor, which runs ``__post_init__`` (conversion and
checks); JAX rebuilds instances with ``tree_unflatten``, which bypasses ``__init__`` so
that tracers, ``None`` placeholders and ``vmap``'s axis specs pass through untouched.
"""

from __future__ import annotations

import dataclasses
from typing import Any, TypeAlias, dataclass_transform

import jax

# A parameter as its constructor takes it (a number, a nested list, a NumPy or JAX array) and
# converts it (a float64 array, checked): what a type checker lets a caller pass and read.
Param: TypeAlias = Any


@dataclass_transform(frozen_default=True, eq_default=False)
def params(cls=None, *, static: tuple[str, ...] = ()):
    def wrap(cls):
        cls = dataclasses.dataclass(frozen=True, eq=False)(cls)
        names = [f.name for f in dataclasses.fields(cls)]
        unknown = set(static) - set(names)
        if unknown:
            raise TypeError(f"{cls.__name__}: static fields {sorted(unknown)} are not fields")
        data = [n for n in names if n not in static]

        def flatten_with_keys(obj):
            return [(jax.tree_util.GetAttrKey(n), getattr(obj, n)) for n in data], tuple(
                getattr(obj, n) for n in static
            )

        def unflatten(aux, children):
            obj = object.__new__(cls)
            for n, v in zip(data, children):
                object.__setattr__(obj, n, v)
            for n, v in zip(static, aux):
                object.__setattr__(obj, n, v)
            return obj

        jax.tree_util.register_pytree_with_keys(
            cls,
            flatten_with_keys,
            unflatten,
            flatten_func=lambda obj: ([getattr(obj, n) for n in data], tuple(getattr(obj, n) for n in static)),
        )
        cls.__repr__ = show_fields
        return cls

    return wrap if cls is None else wrap(cls)


def show_fields(self) -> str:
    """``Name(field=value, ...)`` with concrete values as numbers or nested lists."""

    def show(v):
        try:
            import numpy as np

            a = np.asarray(v)
            return repr(a.item()) if a.ndim == 0 else repr(a.tolist())
        except Exception:  # tracers and nested pytrees
            return repr(v)

    fields = ", ".join(f"{f.name}={show(getattr(self, f.name))}" for f in dataclasses.fields(self))
    return f"{type(self).__name__}({fields})"


def replace_unchecked(obj, **changes):
    """A copy of ``obj`` with fields changed, without running its constructor (for batched or
    traced values inside transformed code, which the single-value checks do not apply to)."""
    out = object.__new__(type(obj))
    for f in dataclasses.fields(obj):
        object.__setattr__(out, f.name, changes.pop(f.name, getattr(obj, f.name)))
    if changes:
        raise TypeError(f"{type(obj).__name__} has no fields {sorted(changes)}")
    return out
