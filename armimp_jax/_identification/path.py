"""The loop linearised along a reach, its noise's time-varying Kalman filter, and the knots' layout.

During a movement (docs/model.md section 19) the loop is not at rest: the hand follows a path and
the arm's ``B(t)``, ``K(t)`` change, so the still arm's single linear loop (``linear.py``) and its
steady-state filter (``kalman.py``) do not hold. Subtracting the ensemble's mean at each sample
leaves the response of the loop linearised *along the mean path* (``s_k+1 = A_k s_k + B_k u_k``,
``y_k = C_k s_k + D_k u_k``, one map per control period), obtained here by forward-mode
differentiation of the simulator's own period step at each period of the noise-free reach, with the
trial's integrator. The noise inputs are ``linear.INPUTS``' plus the four normals that start the
person's force at its stationary state (``voluntary_update`` at ``k = 0``), so the filter's start
is exact: the loop at rest at the path's start, the person's force already going.

The filter is the time-varying one (predictor form, the noise's cross-covariance kept), from that
start, over the record: its innovations ``e_k`` of covariance ``Lambda_k`` whiten the loop's
coloured, non-stationary noise. On it rest the bound along the path (``path_bound.py``) and the
model route over an ensemble (``ensemble_identify.py``).

The knots' layout (``KnotLayout``): the free arm matrices' entries, one ``(2, 2)`` per knot of a
profile (named ``arm.stiffness@t=0.6``, as pooled names carry their group) or one for a constant
matrix.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree
from jax.sharding import PartitionSpec as P

from .._batch import make_mesh
from .._model.movement import Profile
from .._model.plant import plant_model
from .._model.sensors import quiet
from .._pytree import replace_unchecked
from .._simulate import PeriodInputs, Trial, period_step, simulate, simulate_init
from . import kalman, linear

ARM = ("arm.mass", "arm.damping", "arm.stiffness")
# Noise inputs of one period: linear.INPUTS' eight, then the person's force's four starting normals.
N_NOISE = 12


class KnotLayout(NamedTuple):
    """The free arm matrices of a (moving) trial: per name, its knot times (``()``: a constant matrix)."""

    names: tuple
    knots: tuple

    def blocks(self) -> list[tuple[str, float | None]]:
        """``(name, knot time or None)`` per free ``(2, 2)`` matrix, in the vector's order."""
        return [(n, t) for n, ks in zip(self.names, self.knots) for t in (ks or (None,))]

    def size(self) -> int:
        return 4 * len(self.blocks())

    def matrix_names(self) -> list[str]:
        """``"arm.stiffness@t=0.6"`` per knot of a profile, ``"arm.mass"`` for a constant matrix."""
        return [n if t is None else f"{n}@t={t:g}" for n, t in self.blocks()]

    def labels(self) -> list[str]:
        """Every entry's label, row by row: ``"arm.stiffness@t=0.6[0,0]"``."""
        return [f"{m}[{i},{j}]" for m in self.matrix_names() for i in range(2) for j in range(2)]


def knot_layout(trial: Trial, free=ARM, *, where: str = "identify") -> KnotLayout:
    """The layout of ``free`` (arm matrices) on ``trial``'s arm: a profile's knots each free."""
    free = (free,) if isinstance(free, str) else tuple(free)
    bad = [n for n in free if n not in ARM]
    if bad or not free:
        raise ValueError(f"{where}: over an ensemble, free takes arm matrices ({', '.join(ARM)}), got {list(free)}")
    knots = []
    for name in free:
        value = getattr(trial.arm, name.split(".")[1])
        knots.append(tuple(float(t) for t in np.asarray(value.times)) if isinstance(value, Profile) else ())
    return KnotLayout(tuple(free), tuple(knots))


def check_reach_model(trial: Trial, layout: KnotLayout, samples: int, where: str) -> None:
    """One-line refusals of what the reach's bound and model route do not model: a calibrated force
    channel or a force from the motor torques (the loop along the path carries neither), a recorded
    channel without reading noise (a bound would rest on ``kalman.READING_FLOOR``), a knot outside
    the record (nothing would tell its matrix)."""
    s = trial.sensors
    if s.calibrated or s.motor_force:
        raise ValueError(
            f"{where}: a reach's model takes an uncalibrated force transducer (no gain, offset, delay or motor force)"
        )
    if not (s.encoder_on and s.force_on):
        raise ValueError(
            f"{where}: the recorded position and force must each carry reading noise (Sensors(encoder_counts=, "
            "force_noise=)): without it a bound would rest on the 1 nm / 1 uN reading floor, not on the experiment"
        )
    end = (samples - 1) * float(trial.period)
    outside = [t for ks in layout.knots for t in ks if not 0.0 <= t <= end]
    if outside:
        raise ValueError(
            f"{where}: knot at {outside[0]:g} s lies outside the record (0 to {end:g} s): nothing tells its matrix"
        )


def pack(layout: KnotLayout, trial: Trial) -> jnp.ndarray:
    """The vector of ``layout``'s values in ``trial`` (entries row by row, knot by knot)."""
    parts = []
    for name in layout.names:
        value = getattr(trial.arm, name.split(".")[1])
        parts.append(jnp.reshape(value.values if isinstance(value, Profile) else value, (-1,)))
    return jnp.concatenate(parts)


def with_values(layout: KnotLayout, trial: Trial, p) -> Trial:
    """``trial`` with ``layout``'s entries set from ``p`` (traceable: no checks)."""
    arm, at = trial.arm, 0
    for name, ks in zip(layout.names, layout.knots):
        attr, n = name.split(".")[1], max(len(ks), 1)
        block = jnp.reshape(p[at : at + 4 * n], (n, 2, 2))
        at += 4 * n
        value = getattr(arm, attr)
        new = replace_unchecked(value, values=block) if isinstance(value, Profile) else block[0]
        arm = replace_unchecked(arm, **{attr: new})
    return replace_unchecked(trial, arm=arm)


class PathLoop(NamedTuple):
    """The loop linearised along the noise-free reach: per control period ``a`` ``(N, n, n)``,
    ``b`` ``(N, n, 14)``, ``c`` ``(N, 4, n)``, ``d`` ``(N, 4, 14)``; inputs the perturbation (2)
    then the twelve noise inputs of variance ``noise_var`` ``(12,)``."""

    a: jnp.ndarray
    b: jnp.ndarray
    c: jnp.ndarray
    d: jnp.ndarray
    noise_var: jnp.ndarray


def _noise_var(trial: Trial):
    start = jnp.zeros(4) if trial.voluntary is None else jnp.ones(4)
    return jnp.concatenate([linear._noise_variances(trial), start])


def path_loop(trial: Trial, n: int, numerics) -> PathLoop:
    """The trial's loop without its Coulomb friction linearised along its noise-free reach of
    ``n`` periods (module docstring). Traceable; ``numerics`` the simulation's integrator."""
    routed = replace_unchecked(linear.without_friction(trial), sensors=linear._routed(trial.sensors))
    model = plant_model(routed.q0, routed.x0, routed.arm, routed.friction, routed.robot)
    start = simulate_init(routed)
    floats = (start.plant, start.fu_prev, start.x_prev, start.xd_prev, start.memory, start.voluntary)
    s0, unravel = ravel_pytree(floats)
    with_voluntary = trial.voluntary is not None

    def period(s, u, k):
        plant, fu_prev, x_prev, xd_prev, memory, voluntary = unravel(s)
        carry = start._replace(
            plant=plant, fu_prev=fu_prev, x_prev=x_prev, xd_prev=xd_prev, memory=memory, voluntary=voluntary, k=k
        )
        normals = jnp.stack([u[8:10], u[10:12], u[12:14]]) if with_voluntary else None
        inputs = PeriodInputs(force=u[2:4], rate=u[4:6], voluntary=normals, encoder=u[6:8])
        new, out = period_step(routed, model, numerics, carry, u[:2], inputs)
        s_new = ravel_pytree((new.plant, new.fu_prev, new.x_prev, new.xd_prev, new.memory, new.voluntary))[0]
        return s_new, jnp.concatenate([out[0] - routed.x0, out[2]])

    u0 = jnp.zeros(2 + N_NOISE, dtype=s0.dtype)
    ks = jnp.arange(n, dtype=jnp.int32)

    def nominal(s, k):
        return period(s, u0, k)[0], s

    states = jax.lax.scan(nominal, s0, ks)[1]
    (a, b), (c, d) = jax.vmap(jax.jacfwd(period, argnums=(0, 1)), in_axes=(0, None, 0))(states, u0, ks)
    return PathLoop(a, b, c, d, _noise_var(trial))


class PathFilter(NamedTuple):
    """The time-varying Kalman filter of a ``PathLoop``'s noise (scaled outputs ``y / scale``):
    ``a`` ``(N, n, n)``, ``c`` ``(N, 4, n)``, ``gain`` ``(N, n, 4)``, ``chol`` ``(N, 4, 4)`` the
    innovations' covariance's Cholesky factor, ``scale`` ``(4,)`` [m, m, N, N]."""

    a: jnp.ndarray
    c: jnp.ndarray
    gain: jnp.ndarray
    chol: jnp.ndarray
    scale: jnp.ndarray


def path_filter(loop: PathLoop) -> PathFilter:
    """The filter from the reach's exact start (the state known, its noise not yet), over the record."""
    # each period's (Q, R, S) as the still filter's: the noise's share of that period's loop
    periods = linear.LinearLoop(loop.a, loop.b, loop.c, loop.d, loop.noise_var)
    q, r, cross = jax.vmap(kalman.noise_covariances, in_axes=(linear.LinearLoop(0, 0, 0, 0, None),))(periods)
    floor = jnp.asarray(kalman.READING_FLOOR, dtype=r.dtype)
    scale = jnp.sqrt(jnp.mean(jnp.diagonal(r, axis1=1, axis2=2), axis=0) + floor * floor)  # (4,)
    c = loop.c / scale[None, :, None]
    r = r / jnp.outer(scale, scale)[None] + jnp.diag((floor / scale) ** 2)[None]
    cross = cross / scale[None, None, :]

    def step(p, mats):
        a, ck, qk, rk, sk = mats
        lam = ck @ p @ ck.T + rk
        gain = (a @ p @ ck.T + sk) @ jnp.linalg.inv(lam)
        p_new = a @ p @ a.T + qk - gain @ lam @ gain.T
        return 0.5 * (p_new + p_new.T), (gain, jnp.linalg.cholesky(0.5 * (lam + lam.T)))

    p0 = jnp.zeros(loop.a.shape[1:], dtype=loop.a.dtype)
    gain, chol = jax.lax.scan(step, p0, (loop.a, c, q, r, cross))[1]
    return PathFilter(loop.a, c, gain, chol, scale)


def whiten(filt: PathFilter, z):
    """Unit-variance innovations ``(N, 4, ...)`` of the signals ``z`` ``(N, 4, ...)`` [m, m, N, N]:
    ``chol_k^-1 e_k``. Linear in ``z``; trailing axes are columns."""
    zs = z / filt.scale.reshape((1, 4) + (1,) * (z.ndim - 2))

    def step(state, mats):
        a, c, gain, chol, zt = mats
        e = zt - c @ state
        return a @ state + gain @ e, jax.scipy.linalg.solve_triangular(chol, e, lower=True)

    start = jnp.zeros((filt.a.shape[1],) + z.shape[2:], dtype=zs.dtype)
    return jax.lax.scan(step, start, (filt.a, filt.c, filt.gain, filt.chol, zs))[1]


def perturbation_draws(family, key, count: int, samples: int, period: float) -> np.ndarray:
    """``(count, samples, 2)`` draws of a perturbation family (``signal(key, n, period)``), one per
    key of ``jax.random.split(key, count)``."""
    keys = jax.random.split(key, count)
    return np.stack([np.asarray(family.signal(k, samples, period)) for k in keys])


def deterministic(trial: Trial, f, numerics, *, diverged: bool = False):
    """The noise-free recording ``(N, 4)`` (``x - x0`` [m], ``F_h`` [N]) of ``trial`` under ``f``
    (and, with ``diverged``, whether it diverged: the simulation then freezes, finite)."""
    sim = simulate(replace_unchecked(trial, sensors=quiet(trial.sensors), voluntary=None), f, numerics=numerics)
    y = jnp.concatenate([sim.x - trial.x0[None, :], sim.fh], axis=1)
    return (y, sim.diverged) if diverged else y


def response_jacobians(layout: KnotLayout, trial: Trial, p, f, numerics):
    """``(mu (R, N, 4), dmu/dp (R, N, 4, n))``: each repetition's noise-free response to its
    perturbation ``f`` ``(R, N, 2)`` and its derivative in ``layout``'s entries at ``p``."""

    def response(q, fr):
        return deterministic(with_values(layout, trial, q), fr, numerics)

    def one(fr):
        jac, mu = jax.jacfwd(lambda q: (response(q, fr),) * 2, has_aux=True)(p)
        return mu, jac

    return jax.lax.map(one, f)


def split_over_devices(fn, *xs):
    """``fn(*xs)``, a map over the leading axis (reaches, or whole ensembles), each of this process's
    devices mapping its own share (``shard_map``): the model route's simulations use every core.
    Nothing crosses devices inside (a reduction across XLA:CPU devices hung at its collective:
    ``indirect.py``), so callers take the result to the host before reducing. The leading axis is a
    multiple of the devices (``padded_for_devices``); one device, or one that is not: ``fn`` as it is."""
    mesh = make_mesh(jax.local_devices())
    if mesh.size == 1 or xs[0].shape[0] % mesh.size:
        return fn(*xs)
    spec = P("batch")
    return jax.shard_map(fn, mesh=mesh, in_specs=(spec,) * len(xs), out_specs=spec, check_vma=False)(*xs)


def padded_for_devices(*xs):
    """``(xs, n)``: each of ``xs`` with its leading axis (length ``n``) padded to a multiple of this
    process's devices by repeating its last row (keys too), so that ``split_over_devices`` splits it;
    the padded rows' results are dropped (``on_host``)."""
    n, pad = xs[0].shape[0], -xs[0].shape[0] % jax.local_device_count()
    return (xs if pad == 0 else tuple(jnp.concatenate([x, *[x[-1:]] * pad]) for x in xs)), n


def on_host(tree, n: int | None = None):
    """``tree`` as NumPy arrays, each cut to its first ``n`` rows (a split map's padding dropped):
    whatever reduces them next runs on one device, never across them."""
    return jax.tree.map(lambda a: np.asarray(a)[:n], tree)


@functools.partial(jax.jit, static_argnames=("layout", "numerics"))
def _linearised_at(layout, trial, p, f, numerics):
    filt = path_filter(path_loop(with_values(layout, trial, p), f.shape[1], numerics))
    mu, jac = split_over_devices(lambda fs: response_jacobians(layout, trial, p, fs, numerics), f)
    return filt, mu, jac


def linearised_at(layout, trial, p, f, numerics):
    """``(filter, mu (R, N, 4), J (R, N, 4, n))`` at ``p`` (host arrays): one program for every
    repetition. Split over several devices, XLA compiles it otherwise: its round-off differs from
    one device's (4e-14 of the values, measured; the responses' and recordings' do not)."""
    (f,), n = padded_for_devices(f)
    filt, mu, jac = _linearised_at(layout, trial, p, f, numerics)
    return on_host(filt), *on_host((mu, jac), n)


@functools.partial(jax.jit, static_argnames=("layout", "numerics"))
def _responses(layout, trial, p, f, numerics):
    at_p = with_values(layout, trial, p)

    def each(fs):
        return jax.lax.map(lambda fr: deterministic(at_p, fr, numerics, diverged=True), fs)

    return split_over_devices(each, f)


def responses(layout, trial, p, f, numerics):
    """``(mu (R, N, 4), diverged (R,))`` at ``p`` (host arrays)."""
    (f,), n = padded_for_devices(f)
    return on_host(_responses(layout, trial, p, f, numerics), n)


def recordings(trial: Trial, f, keys, numerics):
    """``(y (R, N, 4), diverged (R,))``: what a lab records of ``trial`` (``x - x0`` [m], ``F_h`` [N])
    under each perturbation of ``f`` ``(R, N, 2)`` with its noise, one draw per key of ``keys``
    ``(R,)``; the model route's check and its route through friction simulate ensembles by it."""

    def one(fr, k):
        sim = simulate(trial, fr, key=k, numerics=numerics)
        return jnp.concatenate([sim.x - trial.x0[None, :], sim.fh], axis=1), sim.diverged

    return jax.vmap(one)(f, keys)


@functools.partial(jax.jit, static_argnames=("layout", "numerics"))
def _noisy_responses(layout, trial, p, f, keys, numerics):
    at_p = with_values(layout, trial, p)
    return split_over_devices(lambda fs, ks: recordings(at_p, fs, ks, numerics), f, keys)


def noisy_responses(layout, trial, p, f, keys, numerics):
    """``recordings`` of ``trial`` with ``layout``'s entries at ``p`` (host arrays)."""
    (f, keys), n = padded_for_devices(f, keys)
    return on_host(_noisy_responses(layout, trial, p, f, keys, numerics), n)


@jax.jit
def whiten_centred(filt, z):
    """Each repetition's whitened signal less the ensemble's mean (``W`` is linear)."""
    w = jax.vmap(lambda zr: whiten(filt, zr))(z)
    return w - jnp.mean(w, axis=0, keepdims=True)
