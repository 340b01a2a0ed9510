"""The coupled robot + arm + friction plant (spec section 5): derivative, RK4 step, force sensor.

The continuous state is ``PlantState``: joint angles ``q`` [rad], rates ``qd`` [rad/s],
LuGre bristle states ``z`` [rad], and ``xi = int (x - x0) dt`` [m s] over the current
control period (for the ``"interval_mean"`` acquisition; it integrates the deviation
from ``x0`` so that a robot at rest accumulates an exact zero). Every field is a scalar,
so under ``jax.vmap`` the batch is structure-of-arrays, one ``(B,)`` array per field.

With ``x = x_h = x_r``, the hand force ``F_h = M_h xdd + B_h xd + K_h (x - x0)`` is
substituted into ``M qdd + h + tau_f = J^T (F_u - F_h)`` and solved for ``qdd``::

    (M + J^T M_h J) qdd = J^T (F_u - M_h Jd qd - B_h xd - K_h (x - x0)) - h - tau_f
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax.ad_checkpoint import checkpoint_name

from .._checks import check_choice
from .arm import Arm
from .friction import LuGre, lugre
from .robot import Robot, jacobian_from_trig, mass_matrix_entries


class PlantState(NamedTuple):
    """Continuous state, all scalars: ``q1, q2`` [rad], ``qd1, qd2`` [rad/s], ``z1, z2`` [rad],
    ``xi1, xi2`` [m s]."""

    q1: jnp.ndarray
    q2: jnp.ndarray
    qd1: jnp.ndarray
    qd2: jnp.ndarray
    z1: jnp.ndarray
    z2: jnp.ndarray
    xi1: jnp.ndarray
    xi2: jnp.ndarray


class PlantModel(NamedTuple):
    """Per-trial constants of the plant derivative, all scalars (``(B,)`` under ``vmap``).

    ``x0`` [m] is the equilibrium and ``cq0 = (cos q01, sin q01, cos q02, sin q02)`` the
    trig of ``q0``: displacements ``x - x0`` are formed from trig differences, which are
    exactly zero at ``q = q0`` whatever XLA's FMA contraction does to the fused
    expressions. ``mh``, ``bh``, ``kh`` are the arm's ``(m11, m12, m21, m22)``;
    ``friction`` the LuGre scalars of each joint; ``robot`` the robot's parameters.
    """

    x0: tuple
    cq0: tuple
    mh: tuple
    bh: tuple
    kh: tuple
    friction: tuple
    robot: Robot


def _entries(m):
    return (m[0, 0], m[0, 1], m[1, 0], m[1, 1])


def plant_model(q0, x0, arm: Arm, friction: LuGre, robot: Robot) -> PlantModel:
    """Unpack trial parameters into the scalars the inner loop uses (hoisted out of it)."""
    cq0 = (jnp.cos(q0[0]), jnp.sin(q0[0]), jnp.cos(q0[1]), jnp.sin(q0[1]))
    return PlantModel(
        (x0[0], x0[1]),
        cq0,
        _entries(arm.mass),
        _entries(arm.damping),
        _entries(arm.stiffness),
        (friction.joint(0), friction.joint(1)),
        robot,
    )


def rest_state(q0) -> PlantState:
    """The robot at rest at ``q0`` with relaxed bristles."""
    zero = jnp.zeros_like(q0[0])
    return PlantState(q0[0], q0[1], zero, zero, zero, zero, zero, zero)


class Trig(NamedTuple):
    """``cos q1, sin q1, cos q2, sin q2`` of a state (the only transcendentals of the robot)."""

    c1: jnp.ndarray
    s1: jnp.ndarray
    c2: jnp.ndarray
    s2: jnp.ndarray


def trig_of(s: PlantState) -> Trig:
    return Trig(jnp.cos(s.q1), jnp.sin(s.q1), jnp.cos(s.q2), jnp.sin(s.q2))


def displacement(t: Trig, model: PlantModel):
    """``x - x0`` [m] from the trig of the angles, as trig differences against ``q0``'s:
    exactly 0 at ``q = q0``."""
    c10, s10, c20, s20 = model.cq0
    ls, le = model.robot.shoulder_link, model.robot.elbow_link
    return ls * (t.c1 - c10) + le * (t.c2 - c20), ls * (t.s1 - s10) + le * (t.s2 - s20)


@jax.custom_jvp
def _small_angle_cos_sin(d):
    d2 = d * d
    return 1.0 - d2 * (0.5 - d2 * (1.0 / 24 - d2 / 720)), d * (1.0 - d2 * (1.0 / 6 - d2 * (1.0 / 120 - d2 / 5040)))


@_small_angle_cos_sin.defjvp
def _small_angle_cos_sin_jvp(primals, tangents):
    # The derivatives of cos and sin, not of the truncated series (they differ by
    # d^7/5040, far below round-off): 4% fewer operations in the backward loop body.
    (d,), (t,) = primals, tangents
    c, s = _small_angle_cos_sin(d)
    return (c, s), (-s * t, c * t)


def rotate(t: Trig, d1, d2) -> Trig:
    """``Trig`` of the angles advanced by ``d1``, ``d2`` [rad], by the angle-addition formulas
    with Taylor ``cos/sin`` of the increments (to ``d^6``, ``d^7``: exact to round-off for
    ``|d| < 0.03`` rad; an RK4 substep moves ~1e-6 rad). No transcendental is evaluated."""

    cd1, sd1 = _small_angle_cos_sin(d1)
    cd2, sd2 = _small_angle_cos_sin(d2)
    return Trig(t.c1 * cd1 - t.s1 * sd1, t.s1 * cd1 + t.c1 * sd1, t.c2 * cd2 - t.s2 * sd2, t.s2 * cd2 + t.c2 * sd2)


_SHARED = "armimp_shared_stage_value"

# Why the "grad" kernel marks stage values. XLA:CPU copies chains of cheap operations
# (add, multiply, sin, cos) into every fusion that uses them, and in the backward pass
# of an RK4 substep that multiplies the work. XLA never duplicates a division, so the
# kernel divides the stage values by a runtime 1.0 (exact) and names them for the
# substep checkpoint (sweeps/bench_gradient.py measures the effect).
_DIVIDED = ("trig", "stage", "a", "b")


def _sharer(one):
    """``share(group, *values)`` for the ``"grad"`` kernel (identity when ``one`` is None).

    Values of the groups in ``_DIVIDED`` become ``x / one``, with ``one`` a runtime 1.0:
    exact, one materialised value each, named so that the substep checkpoint saves them
    for the backward pass instead of recomputing the stage."""
    if one is None:
        return lambda group, *values: values

    def share(group, *values):
        if group not in _DIVIDED:
            return values
        return tuple(checkpoint_name(v / one, _SHARED) for v in values)

    return share


def coupled_inertia(model: PlantModel, j, m):
    """Entries ``(a11, a12, a21, a22)`` [kg m^2] of ``A = M + J^T M_h J`` from the Jacobian
    entries ``j`` and the robot's ``m = (M11, M12, M22)``; not symmetric (``M_h`` is not)."""
    j11, j12, j21, j22 = j
    m11, m12, m22 = m
    mh11, mh12, mh21, mh22 = model.mh
    p11 = mh11 * j11 + mh12 * j21
    p12 = mh11 * j12 + mh12 * j22
    p21 = mh21 * j11 + mh22 * j21
    p22 = mh21 * j12 + mh22 * j22
    return (
        m11 + (j11 * p11 + j21 * p21),
        m12 + (j11 * p12 + j21 * p22),
        m12 + (j12 * p11 + j22 * p21),
        m22 + (j12 * p12 + j22 * p22),
    )


def _dynamics(s: PlantState, fu, model: PlantModel, trig: Trig | None = None, share=_sharer(None)):
    """Joint accelerations and the pieces needed for the hand force, at command ``fu`` [N] ``(2,)``.

    ``trig`` (optional) supplies ``cos/sin`` of ``q``; by default they are evaluated.
    ``share`` (``_sharer``) marks the solve's matrix ``"a"`` and right-hand side ``"b"``."""
    c1, s1, c2, s2 = trig_of(s) if trig is None else trig
    # Angle-difference identities instead of cos/sin(q1 - q2): two fewer transcendentals
    # per evaluation (they dominate the cost on CPU), error ~1e-16.
    cos_d = c1 * c2 + s1 * s2
    sin_d = s1 * c2 - c1 * s2
    ex, ey = displacement(Trig(c1, s1, c2, s2), model)
    L_S, L_E = model.robot.shoulder_link, model.robot.elbow_link
    j11, j12, j21, j22 = jacobian_from_trig(model.robot, c1, s1, c2, s2)
    m11, m12, m22 = mass_matrix_entries(model.robot, cos_d)
    mh11, mh12, mh21, mh22 = model.mh
    bh11, bh12, bh21, bh22 = model.bh
    kh11, kh12, kh21, kh22 = model.kh
    qd1sq, qd2sq = s.qd1 * s.qd1, s.qd2 * s.qd2

    xd = j11 * s.qd1 + j12 * s.qd2
    yd = j21 * s.qd1 + j22 * s.qd2
    jdqd_x = -L_S * c1 * qd1sq - L_E * c2 * qd2sq  # Jd qd
    jdqd_y = -L_S * s1 * qd1sq - L_E * s2 * qd2sq

    # Hand force without its J qdd part: M_h Jd qd + B_h xd + K_h (x - x0).
    f0x = (mh11 * jdqd_x + mh12 * jdqd_y) + (bh11 * xd + bh12 * yd) + (kh11 * ex + kh12 * ey)
    f0y = (mh21 * jdqd_x + mh22 * jdqd_y) + (bh21 * xd + bh22 * yd) + (kh21 * ex + kh22 * ey)
    rx, ry = fu[0] - f0x, fu[1] - f0y

    tau_f1, zd1 = lugre(s.qd1, s.z1, model.friction[0])
    tau_f2, zd2 = lugre(s.qd2, s.z2, model.friction[1])
    hc = model.robot.inertia[1] * sin_d
    b1 = (j11 * rx + j21 * ry) - hc * qd2sq - tau_f1
    b2 = (j12 * rx + j22 * ry) + hc * qd1sq - tau_f2
    b1, b2 = share("b", b1, b2)

    a11, a12, a21, a22 = share("a", *coupled_inertia(model, (j11, j12, j21, j22), (m11, m12, m22)))
    det = a11 * a22 - a12 * a21
    qdd1 = (a22 * b1 - a12 * b2) / det
    qdd2 = (a11 * b2 - a21 * b1) / det
    deriv = PlantState(s.qd1, s.qd2, qdd1, qdd2, zd1, zd2, ex, ey)
    jqdd = (j11 * qdd1 + j12 * qdd2, j21 * qdd1 + j22 * qdd2)
    return deriv, (ex, ey), (xd, yd), (f0x, f0y), jqdd


def plant_derivative(s: PlantState, fu, model: PlantModel) -> PlantState:
    """Time derivative of the state under the Cartesian command ``fu`` [N] ``(2,)``."""
    return _dynamics(s, fu, model)[0]


def measure(s: PlantState, fu, model: PlantModel):
    """Ideal sensors at state ``s`` while command ``fu`` acts: ``(x, xd, F_h)``, each ``(2,)``.

    ``F_h`` [N] is the transducer force (the force on the hand), from the same
    acceleration the plant integrates.
    """
    _, (ex, ey), (xd, yd), (f0x, f0y), (ax, ay) = _dynamics(s, fu, model)
    mh11, mh12, mh21, mh22 = model.mh
    fh = jnp.stack([(mh11 * ax + mh12 * ay) + f0x, (mh21 * ax + mh22 * ay) + f0y])
    return jnp.stack([model.x0[0] + ex, model.x0[1] + ey]), jnp.stack([xd, yd]), fh


def rk4_step(s: PlantState, fu, model: PlantModel, h) -> PlantState:
    """One classical Runge-Kutta step of size ``h`` [s] with ``fu`` held constant."""

    def f(state):
        return plant_derivative(state, fu, model)

    def axpy(a, k):
        return jax.tree.map(lambda si, ki: si + a * ki, s, k)

    k1 = f(s)
    k2 = f(axpy(0.5 * h, k1))
    k3 = f(axpy(0.5 * h, k2))
    k4 = f(axpy(h, k3))
    return jax.tree.map(lambda si, a, b, c, d: si + (h / 6.0) * (a + 2.0 * b + 2.0 * c + d), s, k1, k2, k3, k4)


def rk4_step_rotating(s: PlantState, trig: Trig, fu, model: PlantModel, h, *, share=_sharer(None)):
    """``rk4_step`` with the stage angles' ``cos/sin`` obtained by ``rotate`` from ``trig``
    (the values at ``s``) instead of 16 transcendental calls; returns the new state and
    its ``Trig``. Same method, same stages; differs from ``rk4_step`` only by round-off.

    ``share`` (``_sharer`` for the ``"grad"`` kernel) marks the stage ``cos/sin``
    (``"trig"``), the stage states (``"stage"``) and, through ``_dynamics``, the 2x2 solve
    of every stage."""

    def f(state, t):
        return _dynamics(state, fu, model, Trig(*share("trig", *t)), share)[0]

    def stage(a, k):
        return PlantState(*share("stage", *(si + a * ki for si, ki in zip(s, k)))), rotate(trig, a * k.q1, a * k.q2)

    k1 = f(s, trig)
    k2 = f(*stage(0.5 * h, k1))
    k3 = f(*stage(0.5 * h, k2))
    k4 = f(*stage(h, k3))
    incr = jax.tree.map(lambda a, b, c, d: (h / 6.0) * (a + 2.0 * b + 2.0 * c + d), k1, k2, k3, k4)
    return jax.tree.map(jnp.add, s, incr), rotate(trig, incr.q1, incr.q2)


KERNELS = ("fast", "reference", "grad")
CHECKPOINTS = ("period", "substep")  # how the simulation checkpoints a period for reverse mode


def integrate_period(
    s: PlantState,
    fu,
    model: PlantModel,
    *,
    period: float,
    substeps: int,
    kernel: str = "fast",
    checkpoint: str = "period",
) -> PlantState:
    """Advance ``s`` over one control period with ``substeps`` fixed RK4 steps (``lax.scan``).

    ``kernel="reference"`` evaluates ``cos/sin`` at every RK4 stage (``rk4_step``);
    ``"fast"`` evaluates them once per period and carries them through the substeps by
    small-angle rotations (``rk4_step_rotating``), re-seeded exactly every period so the
    rotation's round-off cannot accumulate beyond one period. ``"grad"`` is ``"fast"``
    with the stage values shared (``_sharer``) and saved for reverse mode, which makes
    ``jax.grad`` cheaper (``sweeps/bench_gradient.py``). All agree to round-off.

    ``checkpoint`` says how the caller checkpoints the period (``Numerics``): under
    ``"period"`` the ``"grad"`` kernel's substep checkpoint saves the shared stage values,
    which the backward pass produces one period at a time; under ``"substep"`` (the
    period not checkpointed, every substep's carry on the tape) it saves nothing else.
    """
    check_choice("kernel", kernel, KERNELS)
    check_choice("checkpoint", checkpoint, CHECKPOINTS)
    h = period / substeps
    if kernel == "reference":
        body = jax.checkpoint(lambda state, _: (rk4_step(state, fu, model, h), None), prevent_cse=False)
        return jax.lax.scan(body, s, None, length=substeps)[0]
    # Reverse mode keeps the substep carries (and, for "grad" under period checkpoints,
    # the shared stage values). The runtime 1.0 comes from the state so that XLA cannot
    # fold the divisions away.
    share, policy = _sharer(None), None
    if kernel == "grad":
        share = _sharer(jax.lax.stop_gradient(1.0 + 0.0 * s.q1))
        if checkpoint == "period":
            policy = jax.checkpoint_policies.save_only_these_names(_SHARED)

    @functools.partial(jax.checkpoint, prevent_cse=False, policy=policy)
    def body(carry, _):
        return rk4_step_rotating(*carry, fu, model, h, share=share), None

    return jax.lax.scan(body, (s, trig_of(s)), None, length=substeps)[0][0]
