"""The statistics that indirect inference matches: what a recording says, computed naively.

``identify`` fits the closed-loop model by making these statistics of simulated recordings
agree, on average, with the same statistics of the lab's recording (``indirect.py``). They
need not be unbiased estimates of anything: the simulation maps the truth to their
expectation, friction, sampling and Welch bias included. They are chosen to be cheap,
smooth in the recording and close to the parameters they stand for, so that the map is
near the identity and nearly linear over a few standard errors (docs/identification.md):

- **arm** (``arm_statistics``): the classical route, Welch ``Z = T R^-1`` with the
  perturbation as instrument and ``fit_impedance``'s sampled-data model of the trial's
  acquisition: ``M``, ``B``, ``K`` entries. An instrumental-variable estimate, so the
  person's own force and the sensors' noise move it without biasing it.
- **friction** (``friction_statistics``): per joint, a least-squares regression of the
  torque the robot's motors and the hand exert, ``J(q)^T (F_u - F_h)`` (the controller
  replayed on the recording), on the joint's motion: inertia (``qdd`` of both joints),
  viscous (sliding and pre-sliding parts of ``qd``), Coulomb-like ``qd / sqrt(qd^2 +
  v^2)``, stiction-like (the same, weighted to low speeds) and pre-sliding stiffness
  (``q``), of which the sliding viscous, Coulomb and stiction coefficients are kept (the
  pre-sliding ones were rough in the parameters); and the log of the joint's RMS speed.
  The Coulomb coefficient is close to ``tau_c`` while the joint slides; where the joint
  mostly sticks it says little and need not even rise with ``tau_c`` (a second, wrong
  match was seen at 0.2% of the true torque), but the speed falls steadily as friction
  grows. So friction is fitted to all of them at once (more statistics than parameters,
  weighted; ``indirect.py``), which keeps the match unique.

Pure JAX, single-recording functions: ``jax.vmap`` batches them, ``jax.jvp`` differentiates
them (so the simulation's tangents flow through).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

from .._estimation.estimate import estimate
from .._estimation.fit import fit_impedance
from .._estimation.welch import ESTIMATION_FMAX
from .._model.controllers import Joints, reads_joints
from .._model.movement import setpoint
from .._model.plant import plant_model
from .._model.robot import ik, jacobian
from . import efficient
from .layout import ARM_PARAMETERS, Layout

WELCH_NPERSEG = 1024  # ~1 Hz bins at 1 kHz: more averages, so a smaller spread than long segments
LOWPASS_HZ = 40.0  # positions and torques are smoothed before differencing (encoder steps)
EDGE = 100  # samples left out at each end of the regression (the smoothing's wrap-around)
SLOW_FRACTION = 0.1  # v = this fraction of the joint's RMS speed: the Coulomb-like regressor's knee
# per joint, in this order: the regression's viscous (sliding), Coulomb and stiction
# coefficients, then the log RMS speed
FRICTION_STATISTICS = ("viscous", "coulomb", "stiction", "log speed")


def welch_nperseg(n: int) -> int:
    """Welch segment length for an ``n``-sample record: ``WELCH_NPERSEG``, shorter (a power of two,
    at least 4 segments) for short records."""
    return int(min(WELCH_NPERSEG, 2 ** math.floor(math.log2(max(n // 4, 64)))))


# Welch bins up to ESTIMATION_FMAX that the Welch statistic fits each entry's M, B, K on
MIN_BINS = 3


def check_statistic_record(n: int, period: float, where: str) -> None:
    """One line when an ``n``-sample record at ``1 / period`` [Hz] leaves the Welch statistic's
    segments (``welch_nperseg``) fewer than ``MIN_BINS`` bins in ``0 < f <= ESTIMATION_FMAX``."""
    nperseg = welch_nperseg(n)
    bins = math.floor(ESTIMATION_FMAX * nperseg * period + 1e-9)
    if bins < MIN_BINS:
        # the shortest segment with MIN_BINS bins, and the record welch_nperseg gives it to
        need = 2 ** math.ceil(math.log2(MIN_BINS / (ESTIMATION_FMAX * period) - 1e-9))
        fix = f"record at least {4 * need} samples" if need <= WELCH_NPERSEG else "no record length suffices"
        raise ValueError(
            f"{where}: a record of {n} samples at {1.0 / period:g} Hz leaves the Welch statistic's "
            f"{nperseg}-sample segments {bins} frequency bin(s) up to {ESTIMATION_FMAX:g} Hz; it needs "
            f"{MIN_BINS}: {fix}"
        )


def arm_statistics(trial, f, x, fh):
    """``(M, B, K)`` each ``(2, 2)`` of the classical fit (Welch, ``fit_impedance`` with the
    trial's acquisition model, uniform weights)."""
    n = f.shape[0]
    nperseg = welch_nperseg(n)
    est = estimate(f, x, fh, fs=1.0 / trial.period, nperseg=nperseg, noverlap=3 * nperseg // 4, errors=False)
    fit = fit_impedance(est.Z, est.f, acquisition=trial.acquisition, period=trial.period, se="residual")
    return fit.mass, fit.damping, fit.stiffness


def lowpass(a, period: float, cutoff: float = LOWPASS_HZ):
    """Zero-phase smoothing of ``a`` ``(N, ...)`` along time: gain ``1 / (1 + (f / cutoff)^8)``."""
    freq = jnp.fft.rfftfreq(a.shape[0], period)
    gain = 1.0 / (1.0 + (freq / cutoff) ** 8)
    return jnp.fft.irfft(jnp.fft.rfft(a, axis=0) * gain.reshape((-1,) + (1,) * (a.ndim - 1)), n=a.shape[0], axis=0)


def replay_command(trial, f, x, fh):
    """The controller's commands ``F_u`` ``(N, 2)`` [N] replayed on a recording (velocity by
    backward differences of ``x``: what a lab has)."""
    period = trial.period
    xd = jnp.concatenate([jnp.zeros((1, 2), x.dtype), jnp.diff(x, axis=0) / period])
    ctl = trial.controller
    motion = plant_model(trial.q0, trial.x0, trial.arm, trial.friction, trial.robot).motion
    planned = None if motion is None else motion.path

    def step(memory, inputs):
        extra = {}
        if planned is not None:  # during a reach the controller follows the planned path, as in the simulation
            extra["path"] = setpoint(planned, inputs[4] * period)
        if reads_joints(ctl):  # a joint-space law: the angles of the recorded hand, its rates through J
            q = ik(inputs[0], trial.robot)
            extra["joints"] = Joints(q, jnp.linalg.solve(jacobian(q, trial.robot), inputs[1]), trial.robot)
        fu, memory = ctl.step(memory, *inputs[:3], inputs[3], trial.x0, period, **extra)
        return memory, fu

    k = jnp.arange(x.shape[0], dtype=x.dtype)
    return jax.lax.scan(step, ctl.init(trial.x0), (x, xd, fh, f, k))[1]


def _least_squares(a, b):
    """``argmin |a c - b|`` by the normal equations on unit-norm columns (float64; a handful of
    regressors). Not ``lstsq``: batched SVD and QR hung on XLA:CPU split into several devices."""
    norms = jnp.sqrt(jnp.sum(a * a, axis=0))
    unit = a / norms[None, :]
    return jnp.linalg.solve(unit.T @ unit, unit.T @ b) / norms


def friction_statistics(trial, f, x, fh):
    """``(2, 4)``: per joint, the statistics listed in ``FRICTION_STATISTICS``."""
    period = trial.period
    q = jax.vmap(lambda v: ik(v, trial.robot))(lowpass(x, period))
    qd = jnp.gradient(q, period, axis=0)
    qdd = jnp.gradient(qd, period, axis=0)
    fu = replay_command(trial, f, x, fh)
    tau = jax.vmap(lambda qq, force: jacobian(qq, trial.robot).T @ force)(q, lowpass(fu - fh, period))
    inner = slice(EDGE, q.shape[0] - EDGE)
    rows = []
    for j in range(2):
        v = qd[:, j]
        knee = SLOW_FRACTION * jnp.sqrt(jnp.mean(v * v))
        sliding = v * v / (v * v + knee * knee)
        coulomb = v / jnp.sqrt(v * v + knee * knee)
        regressors = jnp.stack(
            [
                v * sliding,
                v * (1.0 - sliding),
                coulomb,
                coulomb * (1.0 - sliding),
                q[:, j] - jnp.mean(q[:, j]),
                qdd[:, 0],
                qdd[:, 1],
                jnp.ones_like(v),
            ],
            axis=1,
        )[inner]
        speed = 0.5 * jnp.log(jnp.mean(v[inner] * v[inner]))
        coef = _least_squares(regressors, tau[inner, j])
        rows.append(jnp.stack([coef[0], coef[2], coef[3], speed]))
    return jnp.stack(rows)


def statistics(layout: Layout, trial, f, x, fh, arm_stat=None):
    """The statistics matched to ``layout``'s free parameters ``(m,)``, ``m >= layout.size``:
    the linearised loop's (the arm's, the robot's, the force channel's), in the order of ``p``:
    ``arm_stat`` applied to the recording (``efficient.py``: one entry per internal
    parameter) or, when it is ``None``, for each free arm matrix its four classical entries
    (three for a symmetric one: the mean of the off-diagonal pair); then, when any friction
    parameter is free, every friction statistic of both joints (``(2, 4)`` flattened)."""
    parts = []
    if arm_stat is not None:
        parts.append(efficient.apply(arm_stat, trial, x, fh))
    elif any(n in ARM_PARAMETERS for n in layout.names):
        arm = dict(zip(ARM_PARAMETERS, arm_statistics(trial, f, x, fh), strict=True))
        for name, sym in zip(layout.names, layout.symmetric, strict=True):
            if name in ARM_PARAMETERS:
                a = arm[name]
                parts.append(jnp.stack([a[0, 0], 0.5 * (a[0, 1] + a[1, 0]), a[1, 1]]) if sym else a.reshape(-1))
    if layout.friction_names():
        parts.append(friction_statistics(trial, f, x, fh).reshape(-1))
    return jnp.concatenate(parts)


def _internal_labels(layout: Layout) -> list[str]:
    """Names of the internal entries of a layout of the linearised loop's parameters (a symmetric
    matrix's three)."""
    out = []
    for name, sym in zip(layout.names, layout.symmetric, strict=True):
        if sym:
            out += [f"{name}[{k}]" for k in ("0,0", "0,1", "1,1")]
        else:
            out += Layout((name,), (False,)).labels()
    return out


def statistic_labels(layout: Layout) -> list[str]:
    """Names of ``statistics``' entries (``"arm.mass[0,1]"``, ``"friction coulomb[1]"``)."""
    linear = layout.linear()
    out = [] if linear is None else _internal_labels(linear)
    if layout.friction_names():
        out += [f"friction {s}[{j}]" for j in range(2) for s in FRICTION_STATISTICS]
    return out
