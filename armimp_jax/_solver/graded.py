"""A cheaper converged step for stiff friction: ARK4 in momentum form, its frame frozen at
each step's midpoint, with the last substep of each control period graded.

Two measured facts shape it (``sweeps/bench_convergence.py``; the numbers are in
docs/performance.md, "The integrators' convergence"):

1. **Where the error comes from at small Coulomb torques.** The recorded hand force is the
   plant's at the sample instant, and it contains the bristle damping ``sigma1 z'`` with
   ``z' = qd - lambda z`` (``lambda = sigma0 |qd| / g``, huge as ``tau_c -> 0``): an error
   ``dz`` of the bristle state at the sample shows as ``sigma1 lambda dz``. Just after a
   velocity reversal, while the bristles flip (far faster than a control period), a step
   that ends at a sample leaves ``z``, and so the force sample, far off unless it is short;
   the trajectory itself stays accurate. So only the steps that end at a sample need be
   short: ``substeps`` equal steps, the last of them cut into ``TAIL`` (fractions of it),
   shorter towards the sample.
2. **Where the time goes.** XLA:CPU copies the cheap chains behind every value into each
   fusion that reads it. The robot's frame (``J``, ``A^-1``, the trig of the Coriolis
   terms) feeds almost every value of a stage, so evaluating it per stage multiplied the
   work. Here it is evaluated once per step, at the predicted midpoint
   ``q_n + h/2 qd_est`` (``qd_est``: the previous step's mean velocity, or the period's
   initial one). That keeps the method second order in the frame's motion (the error
   terms are odd about the midpoint, and ``sum b_i c_i = 1/2``), and ``q`` moves little
   within a step. The hand's displacement ``x - x0`` (the stiffness forces) is evaluated
   exactly at every stage. The values several fusions read are divided by a runtime 1.0
   (exact), which XLA computes once (as in ``ark.py``).

The method is otherwise ``ARK4``'s (Kennedy & Carpenter's ARK4(3)6L[2]SA, the bristles
implicit: a frozen-``lambda`` 2x2 solve, then one Newton step), so it is stable for every
``tau_c >= 0``.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import ClassVar, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .._model.plant import PlantModel, PlantState, Trig, displacement, moving_arm
from .._model.robot import jacobian_from_trig
from .ark import (
    ARK436,
    MomentumState,
    Tableau,
    _bristled,
    _frame,
    _frozen_solve,
    _mv,
    _newton_step,
    from_momentum,
    solve_static,
    stateless,
    static_rate,
    stiff_static,
    to_momentum,
)
from .common import check_checkpoint, check_kernel


@jax.custom_jvp
def _cos_sin_small(d):
    # Taylor to d^4 / d^5: exact to round-off for |d| < 0.01 rad (the next terms are below
    # 1.4e-15); within a period the angles move about 1e-4 rad, and the trig is evaluated
    # afresh at every period start. Reciprocal constants: XLA keeps a division by a constant.
    d2 = d * d
    return 1.0 - d2 * (0.5 - d2 * (1.0 / 24)), d * (1.0 - d2 * ((1.0 / 6) - d2 * (1.0 / 120)))


@_cos_sin_small.defjvp
def _cos_sin_small_jvp(primals, tangents):
    (d,), (t,) = primals, tangents
    c, s = _cos_sin_small(d)
    return (c, s), (-s * t, c * t)


def _rotate(t: Trig, d1, d2) -> Trig:
    """``Trig`` of the angles advanced by ``d1``, ``d2`` [rad] (angle addition, no transcendental)."""
    cd1, sd1 = _cos_sin_small(d1)
    cd2, sd2 = _cos_sin_small(d2)
    return Trig(t.c1 * cd1 - t.s1 * sd1, t.s1 * cd1 + t.c1 * sd1, t.c2 * cd2 - t.s2 * sd2, t.s2 * cd2 + t.c2 * sd2)


class _Frozen(NamedTuple):
    """What a step holds fixed, from the frame at its midpoint: the maps of the momentum
    balance that depend on ``q`` only, so that a stage's rates are a few products.

    ``ainv``: ``A^-1``; ``c``: ``A^-1 Sigma1`` (``qd = A^-1 p - c z``); ``damping``:
    ``J^T B_h J + diag(sigma2)``; ``stiffness``: ``J^T K_h`` (on ``x - x0``); ``drive``:
    ``J^T F_u``; ``inertial``: the rows ``(L_s (cos q1, sin q1), L_e (cos q2, sin q2)) M_h J``,
    so that ``Jd^T M_h xd = diag(qd) inertial qd``; ``coriolis``: ``-c2 sin(q1 - q2)``, so
    that ``dT/dq1 = -dT/dq2 = coriolis qd1 qd2`` (2x2 matrices as ``(m11, m12, m21, m22)``)."""

    ainv: tuple
    c: tuple
    damping: tuple
    stiffness: tuple
    drive: tuple
    inertial: tuple
    coriolis: jnp.ndarray


def _matmul(a, b):
    a11, a12, a21, a22 = a
    b11, b12, b21, b22 = b
    return (a11 * b11 + a12 * b21, a11 * b12 + a12 * b22, a21 * b11 + a22 * b21, a21 * b12 + a22 * b22)


def _frozen(trig: Trig, fu, model: PlantModel) -> _Frozen:
    """``_Frozen`` at the angles whose ``cos/sin`` are ``trig``, under the command ``fu`` [N]."""
    fr = _frame(trig, model)
    c1, s1, c2, s2 = trig
    j11, j12, j21, j22 = fr.j
    jt = (j11, j21, j12, j22)
    f1, f2 = model.friction
    i11, i12, i21, i22 = fr.ainv
    d1, d2 = f1.state_damping(), f2.state_damping()
    bj = _matmul(jt, _matmul(model.bh, fr.j))
    mj = _matmul(model.mh, fr.j)
    ls, le = model.robot.shoulder_link, model.robot.elbow_link
    return _Frozen(
        ainv=fr.ainv,
        c=(i11 * d1, i12 * d2, i21 * d1, i22 * d2),
        damping=(bj[0] + f1.viscous_coefficient(), bj[1], bj[2], bj[3] + f2.viscous_coefficient()),
        stiffness=_matmul(jt, model.kh),
        drive=_mv(jt, fu[0], fu[1]),
        inertial=(
            ls * (c1 * mj[0] + s1 * mj[2]),
            ls * (c1 * mj[1] + s1 * mj[3]),
            le * (c2 * mj[0] + s2 * mj[2]),
            le * (c2 * mj[1] + s2 * mj[3]),
        ),
        coriolis=-model.robot.inertia[1] * fr.sin_d,
    )


def _solve_bristles(fr: _Frozen, p, r, hg, lam, model: PlantModel, bristled, share):
    """The implicit stage ``z = r + hg (qd(z) - lambda(qd(z)) z)`` for both joints (as
    ``ark._solve_bristles``): a solve with ``lambda`` frozen at ``lam`` (the previous
    stage's), then one Newton step. Returns ``z`` and the rates at the Newton point."""
    f1, f2 = model.friction
    u1, u2 = _mv(fr.ainv, p[0], p[1])
    b1, b2 = bristled
    c11, c12, c21, c22 = fr.c
    c = (c11, c22, jnp.where(b1, hg * c12, 0.0), jnp.where(b2, hg * c21, 0.0))
    z = share(_frozen_solve(r, hg, (u1, u2), lam, c, bristled))
    v1, v2 = share((u1 - c11 * z[0] - c12 * z[1], u2 - c21 * z[0] - c22 * z[1]))
    relax = share((f1.relaxation(v1), f2.relaxation(v2)))
    return _newton_step(z, r, hg, (v1, v2), relax, c, bristled)


def _rates(fr: _Frozen, e, p, z, model: PlantModel, bristled, share):
    """``(qd, p')`` at a stage from the step's frozen maps and the stage's exact
    displacement ``e = x - x0``."""
    f1, f2 = model.friction
    u1, u2 = _mv(fr.ainv, p[0], p[1])
    w1, w2 = _mv(fr.c, z[0], z[1])
    v1, v2 = share((u1 - w1, u2 - w2))
    a1, a2 = _mv(fr.inertial, v1, v2)
    d1, d2 = _mv(fr.damping, v1, v2)
    k1, k2 = _mv(fr.stiffness, e[0], e[1])
    cor = fr.coriolis * v1 * v2
    pd1 = (fr.drive[0] - d1 - k1) + (cor - v1 * a1) - jnp.where(bristled[0], f1.state_stiffness() * z[0], 0.0)
    pd2 = (fr.drive[1] - d2 - k2) - (cor + v2 * a2) - jnp.where(bristled[1], f2.state_stiffness() * z[1], 0.0)
    return (v1, v2), (pd1, pd2)


def _arm_torque(j, v, e, model: PlantModel, t):
    """A moving arm's share of ``p'`` at a stage of time ``t`` [s]: ``J^T (g - B_h(t) J qd -
    K_h(t) (x - x0))`` with the step's frozen ``J`` (``j``), velocities ``v`` and displacement ``e``
    (its frozen maps then hold the viscous friction alone: a moving arm's model has ``bh = kh = 0``)."""
    b, k, g = moving_arm(model, t)
    j11, j12, j21, j22 = j
    xd, yd = j11 * v[0] + j12 * v[1], j21 * v[0] + j22 * v[1]
    fx = -(b[0] * xd + b[1] * yd) - (k[0] * e[0] + k[1] * e[1])
    fy = -(b[2] * xd + b[3] * yd) - (k[2] * e[0] + k[3] * e[1])
    if g is not None:
        fx, fy = fx + g[0], fy + g[1]
    return j11 * fx + j21 * fy, j12 * fx + j22 * fy


def _bristle_rate(v, z, model: PlantModel, bristled):
    lam = tuple(fj.relaxation(vj)[0] for vj, fj in zip(v, model.friction))
    return tuple(jnp.where(b, vj - lj * zj, 0.0) for vj, zj, lj, b in zip(v, z, lam, bristled)), lam


def graded_step(m: MomentumState, v_est, fu, model: PlantModel, h, one, *, tableau: Tableau = ARK436, t=None):
    """One step of size ``h`` [s] (may be traced) with ``fu`` [N] held, the frame frozen at
    ``q + h/2 v_est``. Returns the new state and the step's mean velocity [rad/s] (the next
    step's ``v_est``). ``one`` is a runtime 1.0 from outside the loop (so that the divisions
    by it need no recomputation of it). ``t`` [s]: the step's start, which a moving arm's plant
    needs (stage ``i`` at ``t + c_i h``)."""
    bristled = _bristled(model)
    static, no_state = stiff_static(model), stateless(model)

    def share(tree):
        return jax.tree.map(lambda x: x / one, tree)

    mid = share(_rotate(m.trig, 0.5 * h * v_est[0], 0.5 * h * v_est[1]))
    fr = share(_frozen(mid, fu, model))
    moving = model.motion is not None
    j_mid = share(jacobian_from_trig(model.robot, *mid)) if moving else None
    hg = h * tableau.gamma
    inv_hg = 1.0 / hg
    ks = []  # per stage: (qd, p', x - x0, z'), and the stiff torque's share of p' (STIFF_STATIC)
    lam = None

    def advance(x0, coeffs, field):
        return tuple(x0[j] + h * sum(a * k[field][j] for a, k in zip(coeffs, ks)) for j in range(2))

    for i in range(len(tableau.c)):
        if i == 0:
            p, z = m.p, m.z
            e = share(displacement(m.trig, model))
        else:
            ae, ai = tableau.explicit[i - 1], tableau.implicit[i - 1]
            dq = share(advance((0.0, 0.0), ae, 0))
            e = share(displacement(_rotate(m.trig, *dq), model))
            p, r = share((advance(m.p, ae, 1), advance(m.z, ai, 3)))
            if static:  # the stiff stateless torque implicitly (ark.solve_static)
                rp = share(advance(p, ai, 4))
                p = share(solve_static(fr.ainv, rp, hg, ks[-1][0], model)[0])
            if no_state:
                z = r
            else:
                z, lam = _solve_bristles(fr, p, r, hg, lam, model, bristled, share)
                z = share(z)  # lam is shared within
        v, pdot = _rates(fr, e, p, z, model, bristled, share)
        if moving:
            tau = _arm_torque(j_mid, v, e, model, t + tableau.c[i] * h)
            pdot = (pdot[0] + tau[0], pdot[1] + tau[1])
        if i == 0:
            zd, lam = _bristle_rate(v, z, model, bristled)
        else:
            zd = ((z[0] - r[0]) * inv_hg, (z[1] - r[1]) * inv_hg)
        # v and e are shared already; an implicit stage's z' is three operations away from
        # shared values, cheaper recomputed than divided.
        stage = (v, share(pdot), e, share(zd) if i == 0 else zd)
        if static:
            stage += (share(static_rate(v, model) if i == 0 else ((p[0] - rp[0]) * inv_hg, (p[1] - rp[1]) * inv_hg)),)
        ks.append(stage)
    dq = share(advance((0.0, 0.0), tableau.b, 0))
    p_new = advance(m.p, tableau.b, 1)
    new = MomentumState(
        (m.q[0] + dq[0], m.q[1] + dq[1]),
        advance(p_new, tableau.b, 4) if static else p_new,
        z,  # stiffly accurate: the last stage's z is the step's
        advance(m.xi, tableau.b, 2),
        _rotate(m.trig, *dq),
    )
    return new, (dq[0] / h, dq[1] / h)


@jax.tree_util.register_static
@dataclasses.dataclass(frozen=True, kw_only=True)
class GradedARK4:
    """ARK4 in momentum form, the bristles implicit, with a frame frozen per step and the
    last substep of each period graded (a static, hashable value; see the module docstring).
    Stable for every ``tau_c >= 0``.

    A period of ``substeps`` is integrated as ``substeps - 1`` equal steps ``h`` followed by
    steps of ``h`` times the fractions ``TAIL`` (``step_sizes``): ``substeps + 2`` steps.
    More substeps (``check_numerics``' refinement) shorten the equal steps and the tail
    alike.

    Args:
        kernel: ``"fast"`` (the only one: ``cos/sin`` carried by small-angle rotations).
    """

    kernel: str = "fast"

    method: ClassVar[str] = "gark4"
    KERNELS: ClassVar[tuple[str, ...]] = ("fast",)
    TAIL: ClassVar[tuple[float, ...]] = (0.5, 0.25, 0.25)
    tableau: ClassVar[Tableau] = ARK436

    def __post_init__(self):
        check_kernel(self)

    def step_sizes(self, period: float, substeps: int) -> tuple[float, ...]:
        """The step sizes [s] of one period, in order."""
        h = period / substeps
        return (h,) * (substeps - 1) + tuple(h * f for f in self.TAIL)

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
        """Advance ``s`` over one control period [s] (``step_sizes``), the command ``fu`` [N]
        ``(2,)`` held. Reverse mode keeps one carry per step whatever ``checkpoint``. ``time``:
        the period's start [s], which a moving arm's plant needs (``None`` for a still arm)."""
        check_checkpoint(checkpoint)
        tableau = self.tableau

        # The runtime 1.0 of the shared values, made outside the loop (a loop invariant).
        one = jax.lax.stop_gradient(1.0 + 0.0 * s.q1)
        sizes = self.step_sizes(period, substeps)
        hs = jnp.asarray(sizes)
        start = (to_momentum(s, model), (s.qd1, s.qd2))
        if time is None:

            @functools.partial(jax.checkpoint, prevent_cse=False)
            def body(carry, h):
                return graded_step(*carry, fu, model, h, one, tableau=tableau), None

            m, _ = jax.lax.scan(body, start, hs)[0]
            return from_momentum(m, model)

        @functools.partial(jax.checkpoint, prevent_cse=False)
        def moving_body(carry, step):
            h, t = step
            return graded_step(*carry, fu, model, h, one, tableau=tableau, t=t), None

        offsets = jnp.asarray(np.concatenate([[0.0], np.cumsum(sizes[:-1])]))
        m, _ = jax.lax.scan(moving_body, start, (hs, time + offsets))[0]
        return from_momentum(m, model)
