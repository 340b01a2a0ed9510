"""The arm during a movement (docs/model.md, "The arm during a movement"): ``Profile``, a 2x2 matrix
piecewise linear in time, and ``MinimumJerk``, the equilibrium's path of a reach.

Both are immutable pytrees whose floats are leaves (knot times included, so ``jax.grad`` and
``jax.vmap`` reach them and repetitions with different timings share a batch); the number of
knots is a shape, fixed per compiled program. ``MotionTerms`` and ``arm_forces`` are what the
plant evaluates at every integrator stage: scalars, one per batch element under ``vmap``.
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._checks import as_float64, as_param, is_concrete
from .._pytree import Param, params


def _values(values, n_knots: int, where: str):
    """``values`` as float64 of shape ``(J, 2, 2)``, finite (checked when concrete)."""
    if isinstance(values, jnp.ndarray) or not is_concrete(values):
        arr = as_float64("values", values, where=where)
    else:
        try:
            arr = np.asarray(values, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError(f"{where}: values must be numeric, got {values!r}") from None
    if arr.shape != (n_knots, 2, 2):
        raise ValueError(
            f"{where}: values must have shape (J, 2, 2) = ({n_knots}, 2, 2), one 2x2 matrix per knot time, "
            f"got shape {arr.shape}"
        )
    return as_param("values", arr, (n_knots, 2, 2), where=where)


@params
class Profile:
    """A 2x2 matrix that changes with time: piecewise linear through its knots, constant before
    the first knot and after the last (an immutable pytree of float64 leaves).

    Args:
        times: ``(J,)`` knot times [s], strictly increasing (``J >= 1``).
        values: ``(J, 2, 2)`` the matrix at each knot (the unit of the matrix it stands for: N/m
            for a stiffness, N s/m for a damping).

    A profile with one knot is a constant matrix, and ``Arm`` stores it as one. Knot times and
    values are leaves: ``jax.grad`` and ``jax.vmap`` flow through both, and trials whose profiles
    have as many knots share a batch. Concrete values are checked at once, traced ones when the
    program runs.
    """

    times: Param
    values: Param

    def __post_init__(self):
        w = "Profile"
        times = self.times
        if is_concrete(times) and not isinstance(times, jnp.ndarray):
            try:
                times = np.atleast_1d(np.asarray(times, dtype=np.float64))
            except (TypeError, ValueError):
                raise ValueError(f"{w}: times must be numeric seconds, got {self.times!r}") from None
        if np.ndim(times) != 1 or np.shape(times)[0] < 1:
            raise ValueError(f"{w}: times must be a (J,) array of knot times [s], J >= 1, got shape {np.shape(times)}")
        n = int(np.shape(times)[0])
        times = as_param("times [s]", times, (n,), where=w)
        if is_concrete(times):
            t = np.asarray(times)
            back = np.flatnonzero(np.diff(t) <= 0)
            if back.size:
                i = int(back[0]) + 1
                raise ValueError(
                    f"{w}: knot times must increase strictly, got {t.tolist()} s (knot {i} at {t[i]:g} s does not "
                    f"come after knot {i - 1} at {t[i - 1]:g} s)"
                )
        elif n > 1:
            times = eqx.error_if(times, jnp.any(jnp.diff(times) <= 0), f"{w}: knot times must increase strictly")
        object.__setattr__(self, "times", times)
        object.__setattr__(self, "values", _values(self.values, n, w))

    @property
    def knots(self) -> int:
        """The number of knots ``J``."""
        return int(np.shape(self.times)[-1])

    def __call__(self, t):
        """The matrix at time(s) ``t`` [s]: ``(2, 2)`` for a scalar, ``(..., 2, 2)`` for an array."""
        t = jnp.asarray(t, dtype=jnp.float64)[..., None, None]
        times, values = jnp.asarray(self.times), jnp.asarray(self.values)
        out = jnp.broadcast_to(values[0], t.shape[:-2] + (2, 2))
        lead = (1,) * (t.ndim - 2)  # explicit ranks (tests run with rank promotion raising)
        for j in range(self.knots - 1):
            ramp = jnp.clip((t - times[j]) / (times[j + 1] - times[j]), 0.0, 1.0)
            out = out + ramp * jnp.reshape(values[j + 1] - values[j], lead + (2, 2))
        return out


def _min_jerk(s):
    """``(p, p')`` of the minimum-jerk shape ``p(s) = 10 s^3 - 15 s^4 + 6 s^5`` at ``s`` in [0, 1]."""
    s2 = s * s
    return s2 * s * (10.0 - s * (15.0 - 6.0 * s)), 30.0 * s2 * (1.0 - s) * (1.0 - s)


@params
class MinimumJerk:
    """A minimum-jerk reach of the hand's equilibrium (an immutable pytree of float64 leaves):

        s = clip((t - onset) / duration, 0, 1),   x_e = start + (end - start) (10 s^3 - 15 s^4 + 6 s^5)

    Args:
        start: ``(2,)`` [m], where the hand rests until ``onset`` (the robot starts at rest there).
        end: ``(2,)`` [m], where it rests from ``onset + duration`` on.
        onset: when the reach starts [s], ``>= 0``.
        duration: how long it lasts [s], ``> 0``.

    ``position(t)`` and ``velocity(t)`` (the exact derivative) take scalars or arrays of times.
    """

    start: Param
    end: Param
    onset: Param
    duration: Param

    def __post_init__(self):
        w, set_ = "MinimumJerk", object.__setattr__
        set_(self, "start", as_param("start [m]", self.start, (2,), where=w))
        set_(self, "end", as_param("end [m]", self.end, (2,), where=w))
        set_(self, "onset", _bounded("onset", self.onset, w, strict=False))
        set_(self, "duration", _bounded("duration", self.duration, w, strict=True))

    def _shape(self, t):
        """``(p, p', delta)``: the shape and its slope at ``t``, ``(..., 1)``, and ``end - start``
        shaped to multiply them, ``(1, ..., 2)`` (explicit ranks)."""
        t = jnp.asarray(t, dtype=jnp.float64)[..., None]
        s = jnp.clip((t - self.onset) / self.duration, 0.0, 1.0)
        delta = jnp.reshape(jnp.asarray(self.end) - jnp.asarray(self.start), (1,) * (t.ndim - 1) + (2,))
        return (*_min_jerk(s), delta)

    def offset(self, t):
        """``x_e(t) - start`` [m], ``(..., 2)``: exactly zero before the onset."""
        p, _, delta = self._shape(t)
        return delta * p

    def position(self, t):
        """``x_e(t)`` [m], ``(..., 2)``."""
        offset = self.offset(t)
        return jnp.reshape(jnp.asarray(self.start), (1,) * (offset.ndim - 1) + (2,)) + offset

    def velocity(self, t):
        """``xd_e(t)`` [m/s], ``(..., 2)``: the exact derivative of ``position``."""
        _, slope, delta = self._shape(t)
        return delta * (slope / self.duration)


def _bounded(name, value, where, *, strict: bool):
    """A time [s], finite, ``> 0`` (``strict``) or ``>= 0``."""
    arr = as_param(f"{name} [s]", value, (), where=where)
    bad_text = "> 0" if strict else ">= 0"
    if not is_concrete(arr):
        return eqx.error_if(arr, arr <= 0 if strict else arr < 0, f"{where}: {name} must be {bad_text} s")
    v = float(np.asarray(arr))
    if (v <= 0) if strict else (v < 0):
        raise ValueError(f"{where}: {name} must be {bad_text} s, got {v:g} s")
    return arr


# --- what the plant evaluates at every stage ----------------------------------------------


class ProfileTerms(NamedTuple):
    """A profile as the plant evaluates it: ``first`` the first knot's entries ``(m11, m12, m21,
    m22)``; per segment ``j``, ``knots[j]`` its start [s], ``rates[j] = 1 / (t_j+1 - t_j)`` [1/s]
    and ``steps[j]`` the entries' change over it. A constant matrix has no segments."""

    first: tuple
    knots: tuple
    rates: tuple
    steps: tuple


def profile_terms(value) -> ProfileTerms:
    """``ProfileTerms`` of a ``Profile`` or a constant ``(2, 2)`` matrix (hoisted out of the loop)."""

    def entries(m):
        return (m[0, 0], m[0, 1], m[1, 0], m[1, 1])

    if not isinstance(value, Profile):
        return ProfileTerms(entries(value), (), (), ())
    t, v = value.times, value.values
    segments = range(value.knots - 1)
    return ProfileTerms(
        entries(v[0]),
        tuple(t[j] for j in segments),
        tuple(1.0 / (t[j + 1] - t[j]) for j in segments),
        tuple(entries(v[j + 1] - v[j]) for j in segments),
    )


def profile_at(p: ProfileTerms, t) -> tuple:
    """The entries of a profile at time ``t`` [s] (a scalar)."""
    out = p.first
    for knot, rate, step in zip(p.knots, p.rates, p.steps):
        w = jnp.clip((t - knot) * rate, 0.0, 1.0)
        out = tuple(o + w * d for o, d in zip(out, step))
    return out


class PathTerms(NamedTuple):
    """A reach as the plant evaluates it: ``delta = end - start`` [m] (a pair), ``onset`` [s] and
    ``rate = 1 / duration`` [1/s]."""

    delta: tuple
    onset: jnp.ndarray
    rate: jnp.ndarray


def path_terms(path: MinimumJerk) -> PathTerms:
    delta = jnp.asarray(path.end) - jnp.asarray(path.start)
    return PathTerms((delta[0], delta[1]), path.onset, 1.0 / path.duration)


def path_at(p: PathTerms, t):
    """``(x_e(t) - start, xd_e(t))`` [m, m/s] at time ``t`` [s] (a scalar), each a pair."""
    shape, rate = _min_jerk(jnp.clip((t - p.onset) * p.rate, 0.0, 1.0))
    speed = rate * p.rate
    return (p.delta[0] * shape, p.delta[1] * shape), (p.delta[0] * speed, p.delta[1] * speed)


def setpoint(p: PathTerms, t):
    """What a controller's ``step`` takes as ``path`` at ``t`` [s]: the planned offset
    ``x_d(t) - x0`` [m] and velocity ``xd_e(t)`` [m/s], ``(2,)`` each."""
    offset, velocity = path_at(p, t)
    return jnp.stack(offset), jnp.stack(velocity)


class MotionTerms(NamedTuple):
    """What the plant needs of a moving arm: its damping and stiffness (``ProfileTerms``) and its
    equilibrium's path (``PathTerms``, or ``None`` for a still endpoint)."""

    damping: ProfileTerms
    stiffness: ProfileTerms
    path: PathTerms | None


def arm_forces(m: MotionTerms, t):
    """The moving arm at time ``t`` [s]: ``(B(t), K(t), g(t))``, the entries of ``B_h(t)`` and
    ``K_h(t)`` and the force ``g = K_h (x_e - x_0) + B_h xd_e`` [N] (a pair, or ``None`` for a still
    endpoint), so that ``F_h = M_h xdd + B_h xd + K_h (x - x_0) - g``."""
    b, k = profile_at(m.damping, t), profile_at(m.stiffness, t)
    if m.path is None:
        return b, k, None
    (ox, oy), (vx, vy) = path_at(m.path, t)
    g = ((k[0] * ox + k[1] * oy) + (b[0] * vx + b[1] * vy), (k[2] * ox + k[3] * oy) + (b[2] * vx + b[3] * vy))
    return b, k, g
