"""Classical Runge-Kutta (the paper's method): the step, its three kernels, and ``RK4``,
which advances the plant over one control period."""

from __future__ import annotations

import dataclasses
import functools
from typing import ClassVar

import jax
import jax.numpy as jnp
from jax.ad_checkpoint import checkpoint_name

from .._model.plant import PlantModel, PlantState, Trig, plant_derivative, plant_dynamics, trig_of
from .common import check_checkpoint, check_kernel, rotate

_SHARED = "armimp_shared_stage_value"

# Why the "grad" kernel marks stage values. XLA:CPU copies chains of cheap operations
# (add, multiply, sin, cos) into every fusion that uses them, and in the backward pass
# of an RK4 substep that multiplies the work. XLA never duplicates a division, so the
# kernel divides the stage values by a runtime 1.0 (exact) and names them for the
# substep checkpoint (sweeps/bench_gradient.py measures the effect).
_DIVIDED = ("trig", "stage", "a", "b")


def _unshared(group, *values):
    return values


def _sharer(one):
    """``share(group, *values)`` for the ``"grad"`` kernel (identity when ``one`` is None).

    Values of the groups in ``_DIVIDED`` become ``x / one``, with ``one`` a runtime 1.0:
    exact, one materialised value each, named so that the substep checkpoint saves them
    for the backward pass instead of recomputing the stage."""
    if one is None:
        return _unshared

    def share(group, *values):
        if group not in _DIVIDED:
            return values
        return tuple(checkpoint_name(v / one, _SHARED) for v in values)

    return share


@jax.custom_jvp
def _shared_when_differentiated(x, one):
    """``x`` itself (a forward run compiles to the same program), but under differentiation
    ``x / one`` and its tangent ``t / one``, so that each is computed once.

    Why (the ``"fast"`` kernel): in forward mode the tangents of several parameters form a
    batch while the primal is a scalar chain, and XLA:CPU copied that chain into every
    tangent fusion, once per tangent lane; a Jacobian of 16 parameters cost 20 forward runs
    (``sweeps/bench_gradient.py --jacobian``)."""
    return x


@_shared_when_differentiated.defjvp
def _shared_when_differentiated_jvp(primals, tangents):
    x, one = primals
    return x / one, tangents[0] / one


def _tangent_sharer(one):
    """``share(group, *values)`` for the ``"fast"`` kernel: the groups of ``_DIVIDED``
    through ``_shared_when_differentiated`` (the identity unless differentiated)."""

    def share(group, *values):
        if group not in _DIVIDED:
            return values
        return tuple(_shared_when_differentiated(v, one) for v in values)

    return share


def _stage_times(t, h):
    """The stage times of a step from ``t`` [s] (``None`` for a still arm's plant, which needs none)."""
    return (None,) * 4 if t is None else (t, t + 0.5 * h, t + 0.5 * h, t + h)


def rk4_step(s: PlantState, fu, model: PlantModel, h, t=None) -> PlantState:
    """One classical Runge-Kutta step of size ``h`` [s] with ``fu`` held constant, from time ``t``
    [s] (a moving arm's plant needs it)."""
    t1, t2, t3, t4 = _stage_times(t, h)

    def f(state, time):
        return plant_derivative(state, fu, model, time)

    def axpy(a, k):
        return jax.tree.map(lambda si, ki: si + a * ki, s, k)

    k1 = f(s, t1)
    k2 = f(axpy(0.5 * h, k1), t2)
    k3 = f(axpy(0.5 * h, k2), t3)
    k4 = f(axpy(h, k3), t4)
    return jax.tree.map(lambda si, a, b, c, d: si + (h / 6.0) * (a + 2.0 * b + 2.0 * c + d), s, k1, k2, k3, k4)


def rk4_step_rotating(s: PlantState, trig: Trig, fu, model: PlantModel, h, *, share=_unshared, t=None):
    """``rk4_step`` with the stage angles' ``cos/sin`` obtained by ``rotate`` from ``trig``
    (the values at ``s``) instead of 16 transcendental calls; returns the new state and
    its ``Trig``. Same method, same stages; differs from ``rk4_step`` only by round-off.

    ``share`` (``_sharer`` for the ``"grad"`` kernel) marks the stage ``cos/sin``
    (``"trig"``), the stage states (``"stage"``) and, through ``plant_dynamics``, the 2x2
    solve of every stage. ``t`` [s]: the step's start, which a moving arm's plant needs."""
    t1, t2, t3, t4 = _stage_times(t, h)

    def f(state, tr, time):
        return plant_dynamics(state, fu, model, trig=Trig(*share("trig", *tr)), share=share, t=time).derivative

    def stage(a, k):
        return PlantState(*share("stage", *(si + a * ki for si, ki in zip(s, k)))), rotate(trig, a * k.q1, a * k.q2)

    k1 = f(s, trig, t1)
    k2 = f(*stage(0.5 * h, k1), t2)
    k3 = f(*stage(0.5 * h, k2), t3)
    k4 = f(*stage(h, k3), t4)
    incr = jax.tree.map(lambda a, b, c, d: (h / 6.0) * (a + 2.0 * b + 2.0 * c + d), k1, k2, k3, k4)
    return jax.tree.map(jnp.add, s, incr), rotate(trig, incr.q1, incr.q2)


@jax.tree_util.register_static
@dataclasses.dataclass(frozen=True, kw_only=True)
class RK4:
    """Classical fourth-order Runge-Kutta with fixed steps (the paper's method; a static,
    hashable value). Explicit: diverges once the bristle relaxation rate ``sigma0 |v| / g``
    times the step passes 2.8 (small Coulomb torques; ``ARK3`` is stable there).

    Args:
        kernel: ``"fast"`` (default: ``cos/sin`` carried through the stages by exact
            small-angle rotations), ``"reference"`` (evaluated at every stage) or ``"grad"``
            (``"fast"`` arranged so that reverse-mode gradients cost less). They agree to
            round-off; see ``sweeps/bench_simulate.py`` and ``sweeps/bench_gradient.py``.
    """

    kernel: str = "fast"

    method: ClassVar[str] = "rk4"
    KERNELS: ClassVar[tuple[str, ...]] = ("fast", "reference", "grad")

    def __post_init__(self):
        check_kernel(self)

    def integrate_period(
        self,
        s: PlantState,
        fu,
        model: PlantModel,
        *,
        period: float,
        substeps: int,
        checkpoint: str = "period",
        time=None,
    ) -> PlantState:
        """Advance ``s`` over one control period [s] with ``substeps`` fixed steps (``lax.scan``),
        the command ``fu`` [N] ``(2,)`` held.

        ``"reference"`` evaluates ``cos/sin`` at every stage (``rk4_step``); ``"fast"``
        evaluates them once per period and carries them through the substeps by small-angle
        rotations (``rk4_step_rotating``), re-seeded exactly every period so the rotation's
        round-off cannot accumulate beyond one period. ``"grad"`` is ``"fast"`` with the
        stage values shared (``_sharer``) and saved for reverse mode.

        ``checkpoint`` says how the caller checkpoints the period (``Numerics``): under
        ``"period"`` the ``"grad"`` kernel's substep checkpoint saves the shared stage values,
        which the backward pass produces one period at a time; under ``"substep"`` (the
        period not checkpointed, every substep's carry on the tape) it saves nothing else.

        ``time``: the period's start [s], which a moving arm's plant needs (``None`` for a still arm).
        """
        check_checkpoint(checkpoint)
        h = period / substeps
        # A still arm scans no times (its program is the one it always was); a moving one scans
        # the substeps' start times.
        starts = None if time is None else time + h * jnp.arange(substeps, dtype=jnp.float64)
        if self.kernel == "reference":
            body = jax.checkpoint(lambda state, t: (rk4_step(state, fu, model, h, t), None), prevent_cse=False)
            return jax.lax.scan(body, s, starts, length=substeps)[0]
        # Reverse mode keeps the substep carries (and, for "grad" under period checkpoints,
        # the shared stage values). The runtime 1.0 comes from the state so that XLA cannot
        # fold the divisions away.
        one, policy = jax.lax.stop_gradient(1.0 + 0.0 * s.q1), None
        share = _tangent_sharer(one)
        if self.kernel == "grad":
            share = _sharer(one)
            if checkpoint == "period":
                policy = jax.checkpoint_policies.save_only_these_names(_SHARED)

        @functools.partial(jax.checkpoint, prevent_cse=False, policy=policy)
        def body(carry, t):
            return rk4_step_rotating(*carry, fu, model, h, share=share, t=t), None

        return jax.lax.scan(body, (s, trig_of(s)), starts, length=substeps)[0][0]
