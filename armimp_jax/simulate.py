"""Trial parameters and the simulation loop (spec sections 6-7 and 13).

A trial is one record: the robot starts at rest at the arm location's equilibrium, a
perturbation ``F_Delta`` (``(N, 2)`` [N], one sample per control period) is added to the
controller's command, and the loop records what the acquisition sees. The loop is an
outer ``lax.scan`` over control periods (measure, control, integrate) with an inner
fixed-step RK4 ``lax.scan`` over ``substeps``; controller memory is explicit carry.

``simulate`` is a single-trial function: batch it with ``jax.vmap`` over stacked
``TrialParams`` (see ``stack_trials``) and stacked perturbations. A batch may mix
friction levels, locations and ``mhat``; the static fields (controller, substeps,
acquisition, acceleration estimate) must agree.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ._checks import as_float64, check_choice, check_int, is_concrete, require_x64
from .arm import ArmImpedance, arm_impedance
from .control import (
    ACCEL_ESTIMATES,
    CONTROLLERS,
    ControllerGains,
    ControllerMemory,
    controller_gains,
    controller_init,
    controller_step,
    matvec,
)
from .friction import LuGreParams, friction_params
from .plant import CHECKPOINTS, KERNELS, PlantState, integrate_period, measure, plant_model, rest_state
from .robot import fk, ik
from .tables import CONTROL_PERIOD, DEFAULT_MHAT, DEFAULT_SUBSTEPS, location_endpoint

ACQUISITIONS = ("instant", "interval_mean")
# A trial is flagged as diverged when its state is not finite or a joint has moved this
# far from its equilibrium [rad] (about 0.2 m at the handle; real trials move < 1 cm).
DIVERGENCE_ANGLE = 0.5


@dataclasses.dataclass(frozen=True)
class TrialParams:
    """Everything that defines a trial except the perturbation (an immutable pytree).

    Leaves (float64, may be tracers): ``q0`` ``(2,)`` [rad] and ``x0`` ``(2,)`` [m], the
    equilibrium (``x0 = fk(q0)``); ``arm`` (``ArmImpedance``); ``friction``
    (``LuGreParams``); ``gains`` (``ControllerGains``, holding ``mhat``). Static:
    ``controller``, ``substeps``, ``acquisition``, ``accel_estimate``, ``period`` [s],
    ``kernel``, ``checkpoint``.
    """

    q0: jnp.ndarray
    x0: jnp.ndarray
    arm: ArmImpedance
    friction: LuGreParams
    gains: ControllerGains
    controller: str = "pd"
    substeps: int = DEFAULT_SUBSTEPS
    acquisition: str = "instant"
    accel_estimate: str = "velocity"
    period: float = CONTROL_PERIOD
    kernel: str = "fast"
    checkpoint: str = "period"

    @property
    def mhat(self):
        return self.gains.mhat

    def static_fields(self) -> tuple:
        return (
            self.controller,
            self.substeps,
            self.acquisition,
            self.accel_estimate,
            self.period,
            self.kernel,
            self.checkpoint,
        )


jax.tree_util.register_dataclass(
    TrialParams,
    data_fields=["q0", "x0", "arm", "friction", "gains"],
    meta_fields=["controller", "substeps", "acquisition", "accel_estimate", "period", "kernel", "checkpoint"],
)


def check_mhat(mhat):
    """``mhat`` as a ``(2, 2)`` float64 array; if concrete, it must be finite and positive
    definite (the symmetric part's eigenvalues > 0), hence non-singular."""
    arr = as_float64("mhat", mhat, (2, 2), where="trial_params")
    if is_concrete(arr):
        a = np.asarray(arr)
        eig = np.linalg.eigvalsh(0.5 * (a + a.T)) if np.all(np.isfinite(a)) else np.array([np.nan])
        if not np.all(eig > 0.0):
            raise ValueError(
                f"mhat must be a finite positive definite 2x2 matrix [kg] (eigenvalues of (M + M^T)/2 > 0); "
                f"got {a.tolist()} with symmetric-part eigenvalues {eig.tolist()}"
            )
    return arr


def trial_params(
    controller: str,
    friction_level: int,
    location: int,
    *,
    mhat=None,
    substeps: int = DEFAULT_SUBSTEPS,
    acquisition: str = "instant",
    accel_estimate: str = "velocity",
    kernel: str = "fast",
    checkpoint: str = "period",
) -> TrialParams:
    """Parameters of one trial.

    Args:
        controller: ``"pd"`` or ``"imbic"``.
        friction_level: 0 (none), 1 or 2 (Table 1).
        location: arm location 1-4 (Table 2).
        mhat: IMBIC gain ``(2, 2)`` [kg], default ``0.25 I``; may be a JAX array or tracer
            (values are checked when concrete). Unused by PD but kept, so batches stack.
        substeps: RK4 steps per 1 ms control period (integer >= 1).
        acquisition: ``"instant"`` (samples at ``t_k``) or ``"interval_mean"`` (box-car
            means over the period ending at ``t_k``).
        accel_estimate: IMBIC's acceleration estimate, ``"velocity"`` (default,
            ``(xd_k - xd_k-1)/L``) or ``"position"`` (second difference of ``x``).
        kernel: ``"fast"`` (default: ``cos/sin`` carried through the RK4 stages by
            small-angle rotations), ``"reference"`` (evaluated at every stage),
            ``"grad"`` (``"fast"`` arranged for reverse-mode gradients: about 2x faster
            ``jax.grad``, slower batched forward runs) or ``"batch"`` (``"fast"``
            arranged for CPU batches: 9-20% faster at batch 24-96 in paired runs, but
            the last bits of a trial depend on the batch it runs in). They agree to
            round-off; see ``plant.integrate_period``.
        checkpoint: what reverse mode keeps for the backward pass (gradients agree to
            round-off; forward runs are unaffected). ``"period"`` (default): one carry
            per control period, the substeps recomputed in the backward pass (a few
            hundred bytes per sample).
            ``"substep"``: one carry per RK4 substep, 96 bytes each (480 MB for a 50 s
            trial at 100 substeps, 31 MB for 16 s at 20); with the ``"grad"`` kernel
            gradients take 16-25% less time in paired runs. Memory grows with the batch.
    """
    require_x64("trial_params")
    check_choice("controller", controller, CONTROLLERS)
    check_choice("friction level", friction_level, (0, 1, 2))
    check_choice("arm location", location, (1, 2, 3, 4))
    substeps = check_int("substeps (RK4 steps per control period)", substeps, minimum=1)
    check_choice("acquisition", acquisition, ACQUISITIONS)
    check_choice("accel_estimate", accel_estimate, ACCEL_ESTIMATES)
    check_choice("kernel", kernel, KERNELS)
    check_choice("checkpoint", checkpoint, CHECKPOINTS)
    mhat = check_mhat(DEFAULT_MHAT if mhat is None else mhat)
    q0 = ik(jnp.asarray(location_endpoint(location)))
    x0 = fk(q0)
    return TrialParams(
        q0=q0,
        x0=x0,
        arm=arm_impedance(location),
        friction=friction_params(friction_level),
        gains=controller_gains(q0, mhat),
        controller=controller,
        substeps=substeps,
        acquisition=acquisition,
        accel_estimate=accel_estimate,
        kernel=kernel,
        checkpoint=checkpoint,
    )


def stack_trials(params: list[TrialParams]) -> TrialParams:
    """Stack single-trial parameters along a new leading axis, for ``jax.vmap(simulate)``."""
    if not params:
        raise ValueError("stack_trials needs at least one TrialParams")
    statics = {p.static_fields() for p in params}
    if len(statics) > 1:
        raise ValueError(
            "trials in one batch must share controller, substeps, acquisition, accel_estimate, period, kernel "
            "and checkpoint; "
            f"got {sorted(statics)}"
        )
    return jax.tree.map(lambda *xs: jnp.stack(xs), *params)


class SimResult(NamedTuple):
    """What a trial records, one row per control sample ``k = 0..N-1`` (``t_k = k L``).

    ``x`` [m], ``fh`` [N]: what the acquisition records at ``t_k`` (world-frame position;
    hand force per spec section 6). ``xd`` [m/s], ``q`` [rad], ``z`` [rad]: instantaneous
    values at ``t_k``. ``fu`` [N]: the command applied over ``[t_k, t_k+1)`` (without
    ``F_Delta`` separated: it includes it). All ``(N, 2)`` float64. ``diverged`` (bool)
    and ``diverged_at`` (int, first sample whose state was not finite or left the joint
    range, else -1): from that sample on, every field holds its last good value.
    """

    x: jnp.ndarray
    xd: jnp.ndarray
    fh: jnp.ndarray
    fu: jnp.ndarray
    q: jnp.ndarray
    z: jnp.ndarray
    diverged: jnp.ndarray
    diverged_at: jnp.ndarray


def check_perturbation(f_delta, *, where: str):
    arr = as_float64("f_delta", f_delta, where=where)
    if arr.ndim != 2 or arr.shape[1] != 2 or arr.shape[0] < 1:
        raise ValueError(f"f_delta must have shape (N, 2) with N >= 1 samples, got {arr.shape}")
    return arr


class SimCarry(NamedTuple):
    """Loop state between control periods: the plant state at ``t_k``, the controller memory,
    and ``diverged_at`` (int32, -1 while the trial is sound). ``k`` is the next sample index."""

    plant: PlantState
    memory: ControllerMemory
    diverged_at: jnp.ndarray
    k: jnp.ndarray


def simulate_init(params: TrialParams) -> SimCarry:
    """The loop state of a trial at ``t_0``: robot at rest at ``q0``, relaxed bristles."""
    return SimCarry(
        rest_state(params.q0),
        controller_init(params.x0, params.gains),
        jnp.asarray(-1, dtype=jnp.int32),
        jnp.asarray(0, dtype=jnp.int32),
    )


def simulate_chunk(params: TrialParams, carry: SimCarry, f_delta) -> tuple[SimCarry, SimResult]:
    """Run the samples ``f_delta`` ``(n, 2)`` [N] from ``carry``; returns the new carry and
    the ``n`` recorded rows. Chaining chunks gives bitwise the same numbers as one call of
    ``simulate`` (used for progress reporting and resumable long runs)."""
    require_x64("simulate_chunk")
    f_delta = check_perturbation(f_delta, where="simulate_chunk")
    period, substeps = params.period, params.substeps
    model = plant_model(params.q0, params.x0, params.arm, params.friction)
    x0 = params.x0

    def record(state: PlantState, x, xd, fh, memory):
        if params.acquisition == "instant":
            return x, fh
        xbar = x0 + jnp.stack([state.xi1, state.xi2]) / period
        fbar = (
            matvec(params.arm.mass, (xd - memory.xd_prev) / period)
            + matvec(params.arm.damping, (x - memory.x_prev) / period)
            + matvec(params.arm.stiffness, xbar - x0)
        )
        return xbar, fbar

    def control_period(carry: SimCarry, fd):
        state, memory, diverged_at, k = carry
        # The barriers make each sample one materialised value: otherwise XLA may recompute
        # it in several fusions whose FMA contraction differs (batched vs unbatched programs
        # then disagree in the last bit of the outputs).
        x, xd, fh = jax.lax.optimization_barrier(measure(*jax.lax.optimization_barrier((state, memory.fu_prev)), model))
        x_rec, fh_rec = record(state, x, xd, fh, memory)
        fu, new_memory = controller_step(
            params.controller,
            x,
            xd,
            fd,
            fh,
            memory,
            x0,
            params.gains,
            period=period,
            accel_estimate=params.accel_estimate,
        )
        fu, new_memory = jax.lax.optimization_barrier((fu, new_memory))
        zero = jnp.zeros_like(state.xi1)
        new_state = integrate_period(
            state._replace(xi1=zero, xi2=zero),
            fu,
            model,
            period=period,
            substeps=substeps,
            kernel=params.kernel,
            checkpoint=params.checkpoint,
        )

        finite = jnp.all(jnp.stack([jnp.all(jnp.isfinite(leaf)) for leaf in jax.tree.leaves((new_state, fu))]))
        in_range = (jnp.abs(new_state.q1 - params.q0[0]) < DIVERGENCE_ANGLE) & (
            jnp.abs(new_state.q2 - params.q0[1]) < DIVERGENCE_ANGLE
        )
        diverged_at = jnp.where((diverged_at < 0) & ~(finite & in_range), k + 1, diverged_at)
        frozen = diverged_at >= 0
        keep = jax.tree.map(lambda new, old: jnp.where(frozen, old, new), (new_state, new_memory), (state, memory))
        out = (x_rec, xd, fh_rec, fu, jnp.stack([state.q1, state.q2]), jnp.stack([state.z1, state.z2]))
        return SimCarry(*keep, diverged_at, k + 1), out

    # What reverse mode keeps (inert when nothing is differentiated): with "period" the
    # tape holds one carry per period and the backward pass recomputes its substeps; with
    # "substep" the period is not checkpointed, so the tape holds every substep's carry.
    step = control_period if params.checkpoint == "substep" else jax.checkpoint(control_period, prevent_cse=False)
    carry, (x, xd, fh, fu, q, z) = jax.lax.scan(step, carry, f_delta)
    return carry, SimResult(x, xd, fh, fu, q, z, carry.diverged_at >= 0, carry.diverged_at)


def simulate(params: TrialParams, f_delta) -> SimResult:
    """Simulate one trial driven by the perturbation ``f_delta`` ``(N, 2)`` [N].

    Per sample ``k``: (1) measure ``x_k``, ``xd_k`` and ``F_h,k`` (with ``F_u,k-1`` still
    acting), (2) compute ``F_u,k``, (3) integrate to ``t_k+1`` with ``F_u,k`` held.
    Pure and single-trial; ``jax.vmap(simulate)`` batches it, ``jax.grad`` flows through
    every float leaf of ``params`` and through ``f_delta``.
    """
    require_x64("simulate")
    if not isinstance(params, TrialParams):
        raise ValueError(f"params must be TrialParams (from trial_params), got {type(params).__name__}")
    return simulate_chunk(params, simulate_init(params), f_delta)[1]
