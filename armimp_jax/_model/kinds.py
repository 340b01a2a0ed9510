"""Kinds as classes: the registries of controllers and friction laws, and the schema each
class gives of its own parameters.

A kind (``PD``, ``IMBIC``, ``Admittance``; ``LuGre``, ``CoulombViscous``; a user's own) is an
``equinox.Module`` subclass of ``AbstractController`` or ``AbstractFriction`` that names
itself with a class attribute ``kind = "..."``. Defining the class registers it: configs,
sweep points, ``design.json`` and run records find a kind by that name and its parameters
by the class's own ``UNITS`` (field -> unit, or a tuple of allowed words for a text option),
so no list elsewhere names the kinds. An unknown name is refused in one line that names the
known ones.
"""

from __future__ import annotations

import copy
import dataclasses
import importlib.metadata
import inspect
import types
from typing import Any, NamedTuple

import numpy as np

REQUIRED = object()  # a parameter without a default
ENTRY_POINTS = "armimp_jax.kinds"  # the entry-point group an installed package of kinds names
_loaded_entry_points: list = []  # once loaded in this process: [the entry points that failed]


def load_entry_points() -> list[str]:
    """Import every module of the ``armimp_jax.kinds`` entry-point group once (their classes
    register themselves): a lab's kinds, installed as a package, found by name. Returns the
    entry points that failed to load, each as ``"name: error"`` (the others load regardless)."""
    if _loaded_entry_points:
        return _loaded_entry_points[0]
    failed: list[str] = []
    _loaded_entry_points.append(failed)
    for point in importlib.metadata.entry_points(group=ENTRY_POINTS):
        try:
            point.load()
        except Exception as err:  # an installed package's failure: named where a kind is missing
            failed.append(f"{point.name} ({point.value}): {type(err).__name__}: {err}")
    return failed


def _same_source(a: type, b: type) -> bool:
    """Whether two classes are one definition loaded twice (the same name in the same file); a
    class with no file (defined by ``exec`` or in a session) is told by its name alone as new."""
    try:
        return a.__qualname__ == b.__qualname__ and inspect.getsourcefile(a) == inspect.getsourcefile(b)
    except (TypeError, OSError):  # inspect finds no file for it (exec, __main__)
        return False


class Parameter(NamedTuple):
    """One parameter of a kind: its field ``name``, ``shape`` (``None`` for a text option),
    ``unit`` (or the allowed words of a text option) and ``default`` (``REQUIRED`` where the
    constructor needs it; ``None`` where the kind resolves it itself)."""

    name: str
    shape: tuple | None
    unit: Any
    default: Any


class Registry:
    """The kinds of one extension point by name, in the order they were defined."""

    def __init__(self, what: str):
        self.what = what
        self._kinds: dict[str, type] = {}

    def register(self, cls: type) -> None:
        name = cls.__dict__.get("kind")
        if name is None:  # an abstract class, or a subclass that keeps its parent's kind
            return
        if not isinstance(name, str) or not name.isidentifier() or name != name.lower():
            raise TypeError(f"{cls.__name__}: kind must be a lower-case identifier, got {name!r}")
        old = self._kinds.get(name)
        same = old is None or (old.__module__, old.__qualname__) == (cls.__module__, cls.__qualname__)
        if not same and not _same_source(old, cls):  # a file imported twice, by two names, is one kind
            raise TypeError(f"{cls.__name__}: the {self.what} kind {name!r} is {old.__qualname__}'s already")
        self._kinds[name] = cls

    def names(self) -> tuple[str, ...]:
        return tuple(self._kinds)

    def get(self, name, *, where: str = "") -> type:
        """The class of kind ``name``; a one-line ``ValueError`` naming the known kinds."""
        failed = []
        if isinstance(name, str) and name not in self._kinds:
            failed = load_entry_points()  # a kind of an installed package of kinds registers on import
        cls = self._kinds.get(name) if isinstance(name, str) else None
        if cls is None:
            prefix = f"{where}: " if where else ""
            broken = f"; entry points that failed to load: {'; '.join(failed)}" if failed else ""
            raise ValueError(
                f"{prefix}unknown {self.what} type {name!r}; known: {', '.join(sorted(self._kinds))}"
                f" (a kind of your own: import its file first; the scripts take --import FILE.py){broken}"
            )
        return cls


class Converter:
    """A kind's field converter whose one-line refusals name the kind, the field and its unit
    (``LuGre: tau_c [N m] must be finite, got nan``): ``check(value, where=, name=, unit=)``
    converts and checks the value (``unit`` is ``None`` where ``UNITS`` gives none). The kind's
    base class binds ``where`` (the class's name), ``name`` and ``unit`` when the class is
    defined (``name_fields``); unbound, they are the ``where`` and ``name`` given here."""

    def __init__(self, check, *, where: str, name: str):
        self.check, self.where, self.name, self.unit = check, where, name, None

    def __call__(self, value):
        return self.check(value, where=self.where, name=self.name, unit=self.unit)


def name_fields(cls) -> None:
    """Give each field ``cls`` defines with a ``Converter`` a converter of its own, bound to the
    class, the field and its unit in ``UNITS`` (called by the base classes' ``__init_subclass__``,
    before the dataclass is made: the fields are still the class's attributes). A field object
    two classes or two fields share is copied, so each names its own."""
    units = getattr(cls, "UNITS", None) or {}
    for name, value in list(vars(cls).items()):
        converter = value.metadata.get("converter") if isinstance(value, dataclasses.Field) else None
        if isinstance(converter, Converter):
            bound = Converter(converter.check, where=cls.__name__, name=name)
            bound.unit = units.get(name)
            field = copy.copy(value)
            field.metadata = types.MappingProxyType(dict(value.metadata, converter=bound))
            setattr(cls, name, field)


def check_units(cls) -> None:
    """A kind's ``UNITS`` must name its own fields (checked when the class is defined, from its
    annotations: the dataclass is made after ``__init_subclass__``)."""
    names = set()
    for base in cls.__mro__:
        for name, note in vars(base).get("__annotations__", {}).items():
            if "ClassVar" not in str(note):
                names.add(name)
    unknown = sorted(set(cls.UNITS) - names)
    if unknown:
        raise TypeError(f"{cls.__name__}.UNITS names {unknown}, which are not fields")


def parameters(cls, shape: tuple) -> dict[str, Parameter]:
    """``{name: Parameter}`` of a kind's ``UNITS`` fields, in field order; numeric ones have
    ``shape``, text ones (a tuple of words in ``UNITS``) none."""
    out = {}
    for f in dataclasses.fields(cls):
        if f.name not in cls.UNITS:
            continue
        unit = cls.UNITS[f.name]
        if f.default is not dataclasses.MISSING:
            default = f.default
        elif f.default_factory is not dataclasses.MISSING:
            default = f.default_factory()
        else:
            default = REQUIRED
        out[f.name] = Parameter(f.name, None if isinstance(unit, tuple) else shape, unit, default)
    return out


def record(obj, names) -> dict:
    """``{"type": kind, name: value}`` of ``obj``'s parameters ``names`` as JSON values (arrays
    as nested lists; ``None``, a parameter the kind resolves itself, left out)."""
    out = {"type": type(obj).kind}
    for name in names:
        value = getattr(obj, name)
        if value is None:
            continue
        out[name] = value if isinstance(value, str) else np.asarray(value, dtype=float).tolist()
    return out
