"""Several recordings in one identification: ``Recording``, and the map from the search's one
vector to each recording's own parameters.

A study records several trials, at several postures, and sometimes the robot alone (no arm
on the handle: ``aj.presets.no_arm``). Each recording keeps its own ``Trial`` (posture, controller,
noise), perturbation and length. A free parameter is either **shared** by every recording
(the robot's friction, its inertia, the force channel: one robot) or **per group**: one
value for each group of recordings (the arm at each posture; a recording's ``group`` names
its posture). The search moves one vector ``p``: the shared parameters' internal values, then
each group's; a recording sees its own layout (the shared names, and its group's, in the order
given), gathered from ``p`` by its ``index``. A robot-alone recording has no arm to free: it
sees the shared parameters alone. The recordings are independent, so what one tells about a
shared parameter tightens the others through the joint covariance (``search.py``).
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .._simulate import Trial
from . import layout as lay

# What a robot-alone recording cannot tell: its force reading holds no hand force for the
# force channel's gain or delay to act on (the other recordings tell them).
ALONE_BLIND = ("sensors.force_gain", "sensors.force_delay")


class Recording(NamedTuple):
    """One recording for ``identify``: the ``model`` (a ``Trial`` with every fixed setting and
    the starting values), the commanded perturbation ``f`` ``(N, 2)`` [N], the recorded hand
    position ``x`` [m] and force ``fh`` [N] ``(N, 2)``, and its ``group`` (a posture's name:
    recordings of one group share the per-group parameters; ``None``: a group of its own)."""

    model: Trial
    f: object
    x: object
    fh: object
    group: str | None = None


def robot_alone(trial: Trial) -> bool:
    """Whether the trial has no arm on the handle (every arm matrix zero; concrete values)."""
    return all(not np.any(np.asarray(getattr(trial.arm, n))) for n in ("mass", "damping", "stiffness"))


class Block(NamedTuple):
    """A run of ``p``: the ``layout`` of its parameters, the ``trial`` whose values map them
    (the first recording that sees them), its ``group`` (``None``: shared) and its ``slice``."""

    layout: lay.Layout
    trial: Trial
    group: str | None
    slice: slice


class Pool(NamedTuple):
    """The map of a pooled identification: ``blocks`` of ``p``; per recording its ``layouts``
    and ``indices`` into ``p``; the group of each recording; whether names carry their group."""

    blocks: tuple
    layouts: tuple
    indices: tuple
    groups: tuple
    labelled: bool

    @property
    def size(self) -> int:
        return self.blocks[-1].slice.stop if self.blocks else 0

    def names(self) -> list[str]:
        """The estimated parameters' names: ``"arm.stiffness"``, or ``"arm.stiffness@posture 2"``
        where several groups each have their own."""
        return [self._name(name, b.group) for b in self.blocks for name in b.layout.names]

    def labels(self) -> list[str]:
        """The natural entries' names, e.g. ``"arm.mass@2[0,1]"``."""
        out = []
        for b in self.blocks:
            for lab in b.layout.labels():
                name, bracket, rest = lab.partition("[")
                out.append(self._name(name, b.group) + bracket + rest)
        return out

    def _name(self, name: str, group) -> str:
        return name if group is None or not self.labelled else f"{name}@{group}"


def group_names(recordings) -> tuple[str, ...]:
    """Each recording's group: its own, or its position (``"1"``, ``"2"``, ...)."""
    return tuple(str(i + 1) if r.group is None else str(r.group) for i, r in enumerate(recordings))


def make_pool(recordings, free, symmetric, shared) -> Pool:
    """The blocks of ``p`` and each recording's layout and index (one-line errors for names
    no recording can free). ``shared``: the names one value serves for every recording."""
    groups = group_names(recordings)
    alone = [robot_alone(r.model) for r in recordings]
    shared_names = tuple(n for n in free if n in shared)
    per_group = tuple(n for n in free if n not in shared)
    friction_scopes = {n in shared for n in free if n.startswith("friction.")}
    if len(friction_scopes) > 1:
        raise ValueError("identify: the friction parameters must be all shared or all per group (their maps join them)")
    arm_groups = [g for g, a in zip(groups, alone, strict=True) if not a]
    if any(n in lay.ARM_PARAMETERS for n in shared_names) and not arm_groups:
        raise ValueError("identify: the arm is free but every recording is of the robot alone")
    blocks, start = [], 0
    sym = dict(zip(free, (n in symmetric for n in free), strict=True))

    def add(names, trial, group):
        nonlocal start
        if not names:
            return
        layout = lay.Layout(names, tuple(sym[n] for n in names))
        blocks.append(Block(layout, trial, group, slice(start, start + layout.size)))
        start += layout.size

    for g in set(groups):
        if len({a for a, gg in zip(alone, groups, strict=True) if gg == g}) > 1:
            raise ValueError(f"identify: group {g!r} mixes recordings with and without an arm on the handle")
    if len(set(groups)) == 1:  # one group: one block, in the order given (a single recording's p)
        add(tuple(n for n in free if not (alone[0] and n in lay.ARM_PARAMETERS)), recordings[0].model, groups[0])
        return _finish(blocks, groups, alone, free, sym)
    add(shared_names, recordings[0].model, None)
    seen = {}
    for r, g, a in zip(recordings, groups, alone, strict=True):
        names = tuple(n for n in per_group if not (a and n in lay.ARM_PARAMETERS))
        if g in seen:
            continue
        seen[g] = names
        add(names, r.model, g)
    return _finish(blocks, groups, alone, free, sym)


def _finish(blocks, groups, alone, free, sym) -> Pool:
    """Each recording's layout (the names of the blocks it sees, in the order of ``free``) and
    its index into ``p``."""
    if not blocks:
        raise ValueError("identify: no recording has a parameter to free (the arm is free, but no arm is held)")
    layouts, indices = [], []
    for g, a in zip(groups, alone, strict=True):
        mine = [b for b in blocks if b.group in (None, g)]
        names = tuple(n for n in free if any(n in b.layout.names for b in mine) and not (a and n in ALONE_BLIND))
        index = []
        for name in names:
            b = next(b for b in mine if name in b.layout.names)
            offset = b.slice.start + _offset(b.layout, name)
            index += range(offset, offset + b.layout.n_internal(b.layout.names.index(name)))
        layouts.append(lay.Layout(names, tuple(sym[n] for n in names)))
        indices.append(np.asarray(index, dtype=int))
    labelled = len({b.group for b in blocks if b.group is not None}) > 1
    return Pool(tuple(blocks), tuple(layouts), tuple(indices), groups, labelled)


def _offset(layout: lay.Layout, name: str) -> int:
    k = layout.names.index(name)
    return sum(layout.n_internal(i) for i in range(k))


def pack(pool: Pool):
    """The start ``p`` (each block from its trial's values)."""
    return np.concatenate([np.asarray(lay.pack(b.layout, b.trial)) for b in pool.blocks])


def natural(pool: Pool, p):
    """The natural vector (every entry of every block, in its units) of ``p``, traceable."""
    return _natural(*_static(pool), tuple(b.trial for b in pool.blocks), p)


def natural_with_jacobian(pool: Pool, p):
    """``(natural(p), d natural / d p)`` in one program."""
    return _natural_with_jacobian(*_static(pool), tuple(b.trial for b in pool.blocks), jnp.asarray(p))


def _static(pool: Pool):
    return tuple(b.layout for b in pool.blocks), tuple((b.slice.start, b.slice.stop) for b in pool.blocks)


def _natural(layouts, slices, trials, p):
    return jnp.concatenate([lay.natural(la, p[a:b], t) for la, (a, b), t in zip(layouts, slices, trials, strict=True)])


@functools.partial(jax.jit, static_argnums=(0, 1))
def _natural_with_jacobian(layouts, slices, trials, p):
    return _natural(layouts, slices, trials, p), jax.jacfwd(lambda q: _natural(layouts, slices, trials, q))(p)


def unflatten(pool: Pool, flat) -> dict:
    """A natural vector -> ``{name: array in the parameter's shape}`` (``Pool.names``)."""
    out, i = {}, 0
    for b in pool.blocks:
        for name in b.layout.names:
            shape = b.layout.shape(name)
            n = int(np.prod(shape, dtype=int))
            out[pool._name(name, b.group)] = flat[i : i + n].reshape(shape)
            i += n
    return out


def _same(a, b) -> bool:
    """Whether two pytrees (trials, perturbations) are the same, leaf by leaf."""
    la, lb = jax.tree.leaves(a), jax.tree.leaves(b)
    return (
        jax.tree.structure(a) == jax.tree.structure(b)
        and len(la) == len(lb)
        and all(np.shape(x) == np.shape(y) and np.array_equal(np.asarray(x), np.asarray(y)) for x, y in zip(la, lb))
    )


def templates(recordings, groups) -> list[list[int]]:
    """The recordings that share one binding: the same group, model and perturbation (repeated
    trials at a posture). Their statistics enter as their mean, whose spread is that of one
    over their count; one set of simulated draws and one Jacobian serve them all."""
    out: list[list[int]] = []
    for i, r in enumerate(recordings):
        for t in out:
            first = recordings[t[0]]
            if groups[t[0]] == groups[i] and _same(first.model, r.model) and _same(first.f, r.f):
                t.append(i)
                break
        else:
            out.append([i])
    return out
