"""The person's own force ``F_v`` (docs/model.md section 17): a seeded, band-limited random force.

A person holding the handle is not passive. ``F_v`` is a force the person applies to their
own arm, ``M_h xdd + B_h xd + K_h (x - x0) = F_h + F_v``: the transducer reads
``F_h = M_h xdd + B_h xd + K_h (x - x0) - F_v`` and the robot, which feels ``-F_h``, is
pushed by ``F_v`` as by a command of its own. The force is not measured.

Per axis, independently: white Gaussian noise at the control rate ``1 / L`` (1 kHz)
through a second-order Butterworth low-pass of cut-off ``f_vol`` (``butterworth_sos`` and
``sos_step`` of ``perturbation.py``), scaled so that its stationary RMS is ``sigma_vol``,
and held over each control period like ``F_Delta``. **How the filter starts** (our
choice): in its stationary distribution. Sample 0 draws the filter's state from the
state covariance that white noise settles it into (a discrete Lyapunov equation), so
``F_v`` is stationary from ``t_0`` with no warm-up to discard, whatever the cut-off. Before
``t_0`` (the robot at rest) no voluntary force acts.

Sample ``k`` draws a ``(3, 2)`` standard normal from ``fold_in(fold_in(key,
VOLUNTARY_STREAM), k)`` (row 0 drives the filter, rows 1-2 give the start at ``k = 0``):
a stream apart from the sensor noise's ``fold_in(key, k)`` (``k < 2^31``), so turning
``F_v`` on never changes the sensor noise, and the same key gives the same force
whatever the chunking of the record.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import scipy.linalg

from .._checks import as_param, check_range
from .._pytree import Param, params
from .perturbation import butterworth_sos, sos_step
from .timing import CONTROL_PERIOD

VOLUNTARY_ORDER = 2  # second-order Butterworth (one section)
# fold_in data of the voluntary stream: sample indices are int32, so never this value.
VOLUNTARY_STREAM = 2**32 - 1


@params(static=("cutoff",))
class VoluntaryForce:
    """The person's own force (an immutable pytree; pass it as ``make_trial(..., voluntary=...)``).

    Args:
        std: stationary RMS ``sigma_vol`` [N] per axis (scalar or ``(2,)``), ``>= 0``. A leaf:
            it may be traced (vmapped, differentiated).
        cutoff: Butterworth cut-off ``f_vol`` [Hz], ``> 0`` and below the Nyquist rate of the
            trial's control period (checked by ``make_trial``). Static: it fixes the filter.
    """

    std: Param
    cutoff: float

    def __post_init__(self):
        w = "VoluntaryForce"
        std = as_param("std [N]", self.std, (2,), where=w, broadcast=True)
        object.__setattr__(self, "std", check_range("std", std, where=w, minimum=0.0, unit=" N"))
        c = self.cutoff
        if isinstance(c, bool) or not isinstance(c, (int, float, np.floating, np.integer)) or not 0 < c < math.inf:
            raise ValueError(f"VoluntaryForce: cutoff must be a finite frequency > 0 Hz, got {c!r}")
        object.__setattr__(self, "cutoff", float(c))


class VoluntaryState(NamedTuple):
    """The voluntary force's memory between control periods: the filter state ``(1, 2, 2)``
    (section, TDF-II state, axis) and ``F_v,k-1`` [N] ``(2,)``, the force held over the
    period that ends at the next measurement."""

    filter: jnp.ndarray
    force: jnp.ndarray


@functools.cache
def voluntary_design(cutoff: float, fs: float):
    """Filter of ``F_v`` at sample rate ``fs`` [Hz]: ``(sos (1, 6), gain, start (2, 2))``
    (NumPy). ``gain`` scales the filter's output to unit stationary RMS; ``start`` is a
    Cholesky factor of the stationary covariance of its (transposed direct form II) state,
    in units of that output before ``gain``."""
    sos = butterworth_sos(order=VOLUNTARY_ORDER, cutoff=float(cutoff), fs=float(fs))
    b0, b1, b2, _, a1, a2 = sos[0]
    # sos_step as a state space: z' = A z + B u, y = z[0] + b0 u
    a = np.array([[-a1, 1.0], [-a2, 0.0]])
    b = np.array([b1 - a1 * b0, b2 - a2 * b0])
    cov = scipy.linalg.solve_discrete_lyapunov(a, np.outer(b, b))
    variance = cov[0, 0] + b0**2
    return sos, 1.0 / math.sqrt(variance), np.linalg.cholesky(cov)


def voluntary_init(x0) -> VoluntaryState:
    """Memory at ``t_0``: no force before the record (the filter's start is drawn at ``k = 0``)."""
    zero = jnp.zeros_like(x0)
    return VoluntaryState(jnp.zeros((1, 2, 2), dtype=zero.dtype), zero)


def voluntary_key(key):
    """The voluntary force's stream of the simulation ``key``."""
    return jax.random.fold_in(key, VOLUNTARY_STREAM)


def voluntary_normals(stream, k):
    """The ``(3, 2)`` standard normals of sample ``k`` from ``stream = voluntary_key(key)``: row 0
    drives the filter, rows 1-2 draw its stationary start at ``k = 0``."""
    return jax.random.normal(jax.random.fold_in(stream, k), (3, 2), dtype=jnp.float64)


def voluntary_update(vol: VoluntaryForce, state: VoluntaryState, normal, k, period: float):
    """``F_v,k`` [N] ``(2,)`` and the new memory, from the sample's normals ``(3, 2)``
    (``voluntary_normals``; a linearisation passes its own)."""
    sos, gain, start = voluntary_design(vol.cutoff, 1.0 / period)
    first = jnp.asarray(start) @ normal[1:]  # stationary state (2 states, 2 axes)
    zi = jnp.where(k == 0, first[None], state.filter)
    zi, y = sos_step(jnp.asarray(sos), zi, normal[0])
    force = (vol.std * gain) * y
    return VoluntaryState(zi, force), force


def voluntary_step(vol: VoluntaryForce, state: VoluntaryState, stream, k, period: float):
    """``F_v,k`` [N] ``(2,)`` and the new memory, from ``stream = voluntary_key(key)``."""
    return voluntary_update(vol, state, voluntary_normals(stream, k), k, period)


def voluntary_force(vol: VoluntaryForce, key, n_samples: int, *, period: float = CONTROL_PERIOD):
    """The ``F_v`` ``(n_samples, 2)`` [N] that ``simulate`` applies to a trial with ``vol``
    under ``key`` (the same numbers, from the same stream), for plots and checks."""
    stream = voluntary_key(key)

    def step(state, k):
        return voluntary_step(vol, state, stream, k, period)

    init = voluntary_init(jnp.zeros(2, dtype=jnp.float64))
    return jax.lax.scan(step, init, jnp.arange(n_samples, dtype=jnp.int32))[1]
