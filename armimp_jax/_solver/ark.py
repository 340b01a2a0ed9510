"""Stiff friction: an additive (IMEX) Runge-Kutta step of the plant in momentum form.

Why not classical RK4 everywhere: the bristle state relaxes at ``lambda = sigma0 |v| / g(v)``
[1/s], which grows without bound as ``tau_c -> 0`` (docs/model.md section 4). Explicit RK4 is
stable only while ``lambda h < 2.8``, so small Coulomb torques diverge at any affordable
step. Two changes make every ``tau_c >= 0`` stable:

1. **Momentum form.** The bristle damping ``sigma1 zd`` is the fast part of the friction
   torque; with ``p = A(q) qd + Sigma1 z`` (``A = M + J^T M_h J``, ``Sigma1 = diag(sigma1)``)
   it drops out of the momentum balance::

       p' = dT/dq + Jd^T M_h xd + J^T (F_u - B_h xd - K_h (x - x0)) - sigma0 z - sigma2 qd
       qd = A^-1 (p - Sigma1 z)

   (``T = qd^T M qd / 2``; ``dT/dq - h = Md qd - h`` for the robot's Coriolis ``h``), so
   ``q``, ``p`` and ``xi`` have a non-stiff right-hand side: ``sigma0 z`` stays within the
   Stribeck torque ``g``.
2. **The bristles implicitly.** ``z' = qd - lambda(qd) z`` is the only stiff equation. It
   is integrated by the ESDIRK half of an additive Runge-Kutta pair, the rest by its
   explicit half. A stage's ``z`` solves ``z = r + h gamma (qd(z) - lambda(qd(z)) z)``
   (``qd`` depends on ``z`` through ``p``): one linear 2x2 solve with ``lambda`` frozen,
   which can only pull ``z`` towards ``g sign(qd) / sigma0`` whatever ``lambda h``, then
   one Newton step (``_solve_bristles``). As ``tau_c -> 0`` the bristles vanish
   continuously; where ``g = 0`` there are none (``z' = 0``).

The pair is Kennedy & Carpenter's ARK3(2)4L[2]SA (Appl. Numer. Math. 44, 2003): order 3,
L-stable and stiffly accurate implicit half, four stages (three implicit). The choice and
its cost against RK4 are measured by ``sweeps/bench_convergence.py``.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import ClassVar, NamedTuple

import jax
import jax.numpy as jnp

from .._model.plant import (
    PlantModel,
    PlantState,
    Trig,
    coupled_inertia,
    displacement,
    moving_arm,
    trig_of,
    trig_of_angles,
)
from .._model.robot import jacobian_from_trig, mass_matrix_entries
from .common import check_checkpoint, check_kernel, rotate


class Tableau(NamedTuple):
    """An additive Runge-Kutta pair sharing ``c`` and ``b``: ``explicit`` and ``implicit``
    are the rows (stages 2..s) of the strictly lower parts, ``gamma`` the implicit diagonal
    (stage 1 explicit in both halves)."""

    explicit: tuple
    implicit: tuple
    gamma: float
    b: tuple
    c: tuple


def _ark324() -> Tableau:
    g = 1767732205903 / 4055673282236
    b = (1471266399579 / 7840856788654, -4482444167858 / 7529755066697, 11266239266428 / 11593286722821, g)
    explicit = (
        (2 * g,),
        (5535828885825 / 10492691773637, 788022342437 / 10882634858940),
        (6485989280629 / 16251701735622, -4246266847089 / 9704473918619, 10755448449292 / 10357097424841),
    )
    implicit = ((g,), (2746238789719 / 10658868560708, -640167445237 / 6845629431997), b[:3])
    return Tableau(explicit, implicit, g, b, (0.0, 2 * g, 3 / 5, 1.0))


def _ark436() -> Tableau:
    g = 0.25
    b = (82889 / 524892, 0.0, 15625 / 83664, 69875 / 102672, -2260 / 8211, g)
    explicit = (
        (0.5,),
        (13861 / 62500, 6889 / 62500),
        (-116923316275 / 2393684061468, -2731218467317 / 15368042101831, 9408046702089 / 11113171139209),
        (
            -451086348788 / 2902428689909,
            -2682348792572 / 7519795681897,
            12662868775082 / 11960479115383,
            3355817975965 / 11060851509271,
        ),
        (
            647845179188 / 3216320057751,
            73281519250 / 8382639484533,
            552539513391 / 3454668386233,
            3354512671639 / 8306763924573,
            4040 / 17871,
        ),
    )
    implicit = (
        (g,),
        (8611 / 62500, -1743 / 31250),
        (5012029 / 34652500, -654441 / 2922500, 174375 / 388108),
        (15267082809 / 155376265600, -71443401 / 120774400, 730878875 / 902184768, 2285395 / 8070912),
        b[:5],
    )
    return Tableau(explicit, implicit, g, b, (0.0, 0.5, 83 / 250, 31 / 50, 17 / 20, 1.0))


ARK324 = _ark324()
ARK436 = _ark436()


class _Frame(NamedTuple):
    """What a stage needs from ``q``: the trig, ``J`` entries, ``sin(q1 - q2)``, ``A`` and ``A^-1``."""

    trig: Trig
    j: tuple
    sin_d: jnp.ndarray
    a: tuple
    ainv: tuple


def _frame(trig: Trig, model: PlantModel) -> _Frame:
    c1, s1, c2, s2 = trig
    cos_d = c1 * c2 + s1 * s2
    sin_d = s1 * c2 - c1 * s2
    j = jacobian_from_trig(model.robot, c1, s1, c2, s2)
    a = coupled_inertia(model, j, mass_matrix_entries(model.robot, cos_d))
    a11, a12, a21, a22 = a
    k = 1.0 / (a11 * a22 - a12 * a21)  # one division, four products: divisions dominate the cost
    return _Frame(trig, j, sin_d, a, (a22 * k, -a12 * k, -a21 * k, a11 * k))


def _mv(m, x1, x2):
    return m[0] * x1 + m[1] * x2, m[2] * x1 + m[3] * x2


def _bristled(model: PlantModel):
    """Per joint: has it a bristle state (the friction law's ``has_state``: a bool, possibly
    traced)? Without one ``z' = 0``."""
    return tuple(p.has_state() for p in model.friction)


def stateless(model: PlantModel) -> bool:
    """Whether the friction law has no bristle state on either joint, known when tracing (the
    bristle solve is then skipped: ``z`` stays as it is)."""
    return all(b is False for b in _bristled(model))


def stiff_static(model: PlantModel) -> bool:
    """Whether the friction law has a stiff stateless torque to take implicitly. Such a law has
    no bristle state (refused otherwise: the two implicit parts are solved apart)."""
    if not type(model.friction[0]).STIFF_STATIC:
        return False
    if not stateless(model):
        raise TypeError(f"{type(model.friction[0]).__name__}: a STIFF_STATIC friction law cannot have a bristle state")
    return True


def _velocity(fr: _Frame, p, z, model: PlantModel):
    """``qd = A^-1 (p - Sigma1 z)`` [rad/s]."""
    f1, f2 = model.friction
    return _mv(fr.ainv, p[0] - f1.state_damping() * z[0], p[1] - f2.state_damping() * z[1])


def _solve2(m11, m12, m21, m22, r1, r2):
    k = 1.0 / (m11 * m22 - m12 * m21)
    return (m22 * r1 - m12 * r2) * k, (m11 * r2 - m21 * r1) * k


def _solve_bristles(fr: _Frame, p, r, hg, z, lam, model: PlantModel, bristled):
    """The implicit stage ``F(z) = z - r - hg (qd(z) - lambda(qd(z)) z) = 0`` for both joints,
    from the guess ``z`` with relaxation rates ``lam`` (the previous stage's). Returns the
    stage's ``z`` and the rates at the Newton point (the next stage's guess).

    First a solve with ``lambda`` frozen at ``lam``: linear, and it can only pull ``z``
    towards ``g sign(qd) / sigma0``, whatever ``lambda h`` (the stiff limit's safeguard).
    Then one Newton step from there: the frozen pass alone contracts by only about
    ``h sigma1 / A`` where the friction is not stiff, and a second Newton step changed no
    result (``sweeps/bench_convergence.py`` data). A joint without bristles keeps ``z = r``."""
    f1, f2 = model.friction
    u1, u2 = _mv(fr.ainv, p[0], p[1])
    i11, i12, i21, i22 = fr.ainv
    b1, b2 = bristled
    # qd(z) = u - C z with C = A^-1 Sigma1, so for frozen lambda: (I + hg (C + Lambda)) z = r + hg u.
    d1, d2 = f1.state_damping(), f2.state_damping()
    c11, c12, c21, c22 = i11 * d1, i12 * d2, i21 * d1, i22 * d2
    c = (c11, c22, jnp.where(b1, hg * c12, 0.0), jnp.where(b2, hg * c21, 0.0))
    z = _frozen_solve(r, hg, (u1, u2), lam, c, bristled)
    v1, v2 = u1 - c11 * z[0] - c12 * z[1], u2 - c21 * z[0] - c22 * z[1]
    relax = f1.relaxation(v1), f2.relaxation(v2)
    return _newton_step(z, r, hg, (v1, v2), relax, c, bristled)


# Newton steps of the stiff stateless torque's stage solve after its secant solve (a third
# changed no result in sweeps/bench_convergence.py's tanh law runs).
STATIC_NEWTON_STEPS = 2


def _secant(f, v):
    """``static_torque(v) / v`` [N m s/rad] of one joint (its slope where ``v = 0``): the damper
    that gives the law's torque at ``v``."""
    zero = v == 0.0
    return jnp.where(zero, f.static_slope(v), f.static_torque(v) / jnp.where(zero, 1.0, v))


def solve_static(ainv, r, hg, v_guess, model: PlantModel):
    """``p`` of the implicit stage ``p = r - hg phi(A^-1 p)`` for both joints (``phi``: the
    friction law's stiff stateless torque; no bristle state) and the velocity ``A^-1 p`` there.

    First a solve with ``phi`` replaced by its secant at ``v_guess`` (the previous stage's
    velocity): linear, and a damper of any size keeps it stable, as the frozen bristle solve
    does. Then ``STATIC_NEWTON_STEPS`` Newton steps on the stage equation itself."""
    f1, f2 = model.friction
    i11, i12, i21, i22 = ainv
    s1, s2 = hg * _secant(f1, v_guess[0]), hg * _secant(f2, v_guess[1])
    p = _solve2(1.0 + s1 * i11, s1 * i12, s2 * i21, 1.0 + s2 * i22, r[0], r[1])
    for _ in range(STATIC_NEWTON_STEPS):
        v1, v2 = _mv(ainv, p[0], p[1])
        d1, d2 = hg * f1.static_slope(v1), hg * f2.static_slope(v2)
        g1 = p[0] - r[0] + hg * f1.static_torque(v1)
        g2 = p[1] - r[1] + hg * f2.static_torque(v2)
        dp = _solve2(1.0 + d1 * i11, d1 * i12, d2 * i21, 1.0 + d2 * i22, g1, g2)
        p = (p[0] - dp[0], p[1] - dp[1])
    return p, _mv(ainv, p[0], p[1])


def static_rate(v, model: PlantModel):
    """``-phi(v)`` [N m] per joint: the stiff stateless torque's share of ``p'`` from the formula."""
    return tuple(-f.static_torque(vj) for f, vj in zip(model.friction, v))


def _frozen_solve(r, hg, u, lam, c, bristled):
    """``z`` of ``(I + hg (C + Lambda)) z = r + hg u``, ``lambda`` frozen at ``lam``, where ``u``
    is the velocity at ``z = 0`` and ``c`` holds ``C``'s diagonal and ``hg`` times its
    off-diagonal (0 for a joint without bristles, which keeps ``z = r``)."""
    c11, c22, m12, m21 = c
    b1, b2 = bristled
    return _solve2(
        jnp.where(b1, 1.0 + hg * (c11 + lam[0]), 1.0),
        m12,
        m21,
        jnp.where(b2, 1.0 + hg * (c22 + lam[1]), 1.0),
        jnp.where(b1, r[0] + hg * u[0], r[0]),
        jnp.where(b2, r[1] + hg * u[1], r[1]),
    )


def _newton_step(z, r, hg, v, relax, c, bristled):
    """One Newton step on ``F(z) = z - r - hg (qd - lambda(qd) z)`` from ``z``, where the
    velocities are ``v`` and the relaxation rates and slopes ``relax``; ``c`` as for
    ``_frozen_solve``. Returns the
    stage's ``z`` and the rates there (ARK and GradedARK4 alike)."""
    (lam1, dlam1), (lam2, dlam2) = relax
    c11, c22, m12, m21 = c
    b1, b2 = bristled
    # dF/dz = I + hg ((I - diag(z lambda')) C + Lambda)
    w1, w2 = 1.0 - z[0] * dlam1, 1.0 - z[1] * dlam2
    d1, d2 = _solve2(
        jnp.where(b1, 1.0 + hg * (w1 * c11 + lam1), 1.0),
        w1 * m12,
        w2 * m21,
        jnp.where(b2, 1.0 + hg * (w2 * c22 + lam2), 1.0),
        jnp.where(b1, z[0] - r[0] - hg * (v[0] - lam1 * z[0]), 0.0),
        jnp.where(b2, z[1] - r[1] - hg * (v[1] - lam2 * z[1]), 0.0),
    )
    return (z[0] - d1, z[1] - d2), (lam1, lam2)


def _explicit_rates(fr: _Frame, p, z, fu, model: PlantModel, bristled, t=None):
    """``(qd, p', x - x0)`` at a stage (at time ``t`` [s], which a moving arm needs): everything but
    the bristles, none of it stiff."""
    c1, s1, c2, s2 = fr.trig
    j11, j12, j21, j22 = fr.j
    v1, v2 = _velocity(fr, p, z, model)
    ex, ey = displacement(fr.trig, model)
    xd, yd = j11 * v1 + j12 * v2, j21 * v1 + j22 * v2
    wx, wy = _mv(model.mh, xd, yd)  # M_h xd
    bh, kh, g = (model.bh, model.kh, None) if model.motion is None else moving_arm(model, t)
    bx, by = _mv(bh, xd, yd)
    kx, ky = _mv(kh, ex, ey)
    fx, fy = fu[0] - bx - kx, fu[1] - by - ky
    if g is not None:  # the moving equilibrium's pull (plant.moving_arm)
        fx, fy = fx + g[0], fy + g[1]
    dtdq = -model.robot.inertia[1] * fr.sin_d * v1 * v2  # dT/dq1 = -dT/dq2
    ls, le = model.robot.shoulder_link, model.robot.elbow_link
    f1, f2 = model.friction
    # Jd^T M_h xd, with Jd = [[-ls c1 qd1, -le c2 qd2], [-ls s1 qd1, -le s2 qd2]].
    pd1 = dtdq - ls * v1 * (c1 * wx + s1 * wy) + (j11 * fx + j21 * fy) - f1.viscous_coefficient() * v1
    pd2 = -dtdq - le * v2 * (c2 * wx + s2 * wy) + (j12 * fx + j22 * fy) - f2.viscous_coefficient() * v2
    pd1 = pd1 - jnp.where(bristled[0], f1.state_stiffness() * z[0], 0.0)
    pd2 = pd2 - jnp.where(bristled[1], f2.state_stiffness() * z[1], 0.0)
    return (v1, v2), (pd1, pd2), (ex, ey)


class MomentumState(NamedTuple):
    """The integrator's variables: ``q`` [rad], ``p`` [kg m^2/s], ``z`` [rad], ``xi`` [m s]
    (pairs) and the ``Trig`` of ``q``."""

    q: tuple
    p: tuple
    z: tuple
    xi: tuple
    trig: Trig


def _bristle_rate(v, z, model: PlantModel, bristled):
    """``z' = qd - lambda z`` from the formula (0 without bristles), and ``lambda``."""
    lam = tuple(fj.relaxation(vj)[0] for vj, fj in zip(v, model.friction))
    return tuple(jnp.where(b, vj - lj * zj, 0.0) for vj, zj, lj, b in zip(v, z, lam, bristled)), lam


def to_momentum(s: PlantState, model: PlantModel) -> MomentumState:
    trig = trig_of(s)
    fr = _frame(trig, model)
    m1, m2 = _mv(fr.a, s.qd1, s.qd2)
    f1, f2 = model.friction
    p = (m1 + f1.state_damping() * s.z1, m2 + f2.state_damping() * s.z2)
    return MomentumState((s.q1, s.q2), p, (s.z1, s.z2), (s.xi1, s.xi2), trig)


def from_momentum(m: MomentumState, model: PlantModel) -> PlantState:
    return PlantState(*m.q, *_velocity(_frame(m.trig, model), m.p, m.z, model), *m.z, *m.xi)


def ark_step(m: MomentumState, fu, model: PlantModel, h, *, tableau: Tableau = ARK324, rotating: bool = True, t=None):
    """One additive Runge-Kutta step of size ``h`` [s] with ``fu`` [N] held. ``rotating``
    carries ``cos/sin`` through the stages by ``rotate`` (as the ``"fast"`` RK4 kernel
    does) instead of evaluating them. A friction law's stiff stateless torque (``STIFF_STATIC``)
    is the implicit half's share of ``p'`` (``solve_static``); its bristles, ``z'``. ``t`` [s]:
    the step's start, which a moving arm's plant needs (stage ``i`` at ``t + c_i h``)."""
    bristled = _bristled(model)
    static, no_state = stiff_static(model), stateless(model)
    # XLA:CPU copies chains of cheap operations into every fusion that uses them, so a later
    # stage's fusion would recompute the earlier stages (docs/performance.md has the cost).
    # XLA never duplicates a division: each stage's inputs, solve and rates are divided by a
    # runtime 1.0 (exact) and so computed once.
    one = jax.lax.stop_gradient(1.0 + 0.0 * m.q[0])

    def share(tree):
        return jax.tree.map(lambda x: x / one, tree)

    hg = h * tableau.gamma
    inv_hg = 1.0 / hg
    ks = []  # per stage: (qd, p', x - x0, z'), and the stiff torque's share of p' (STIFF_STATIC)
    lam = None  # the latest relaxation rates, from the first stage on

    def advance(x0, coeffs, field):
        return tuple(x0[j] + h * sum(a * k[field][j] for a, k in zip(coeffs, ks)) for j in range(2))

    def angles(q):
        return (m.q[0] + q[0], m.q[1] + q[1])

    for i in range(len(tableau.c)):
        if i == 0:
            fr, p, z = _frame(m.trig, model), m.p, m.z
        else:
            ae, ai = tableau.explicit[i - 1], tableau.implicit[i - 1]
            dq = advance((0.0, 0.0), ae, 0)
            trig = rotate(m.trig, *dq) if rotating else trig_of_angles(angles(dq))
            fr, p, r = share((_frame(trig, model), advance(m.p, ae, 1), advance(m.z, ai, 3)))
            if static:
                rp = share(advance(p, ai, 4))
                p = share(solve_static(fr.ainv, rp, hg, ks[-1][0], model)[0])
            if no_state:
                z = r
            else:
                z, lam = share(_solve_bristles(fr, p, r, hg, z, lam, model, bristled))
        v, pdot, e = _explicit_rates(fr, p, z, fu, model, bristled, None if t is None else t + tableau.c[i] * h)
        # An implicit stage's z' is its own (exact for the solved stage equation), not the
        # formula's, which would multiply the solver's residual by lambda. The first stage
        # needs the formula: the explicit half is not FSAL (its last stage is not the step).
        if i == 0:
            zd, lam = _bristle_rate(v, z, model, bristled)
        else:
            zd = ((z[0] - r[0]) * inv_hg, (z[1] - r[1]) * inv_hg)
        stage = (v, pdot, e, zd)
        if static:  # likewise the stiff torque's share of p'
            stage += (static_rate(v, model) if i == 0 else ((p[0] - rp[0]) * inv_hg, (p[1] - rp[1]) * inv_hg),)
        ks.append(share(stage))
    dq = advance((0.0, 0.0), tableau.b, 0)
    trig = rotate(m.trig, *dq) if rotating else trig_of_angles(angles(dq))
    p_new = advance(m.p, tableau.b, 1)
    if static:
        p_new = advance(p_new, tableau.b, 4)
    # Stiffly accurate: the last stage's z is the step's.
    return MomentumState(angles(dq), p_new, z, advance(m.xi, tableau.b, 2), trig)


@dataclasses.dataclass(frozen=True, kw_only=True)
class _ARK:
    """An additive Runge-Kutta pair in momentum form, the bristles implicit (a static,
    hashable value; see the module docstring). Stable for every ``tau_c >= 0``.

    Args:
        kernel: ``"fast"`` (default: ``cos/sin`` carried through the stages by ``rotate``,
            as RK4's ``"fast"`` kernel does) or ``"reference"`` (evaluated at every stage).
    """

    kernel: str = "fast"

    KERNELS: ClassVar[tuple[str, ...]] = ("fast", "reference")
    method: ClassVar[str]
    tableau: ClassVar[Tableau]

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
        """Advance ``s`` over one control period [s] with ``substeps`` ARK steps (``lax.scan``),
        the command ``fu`` [N] ``(2,)`` held. Reverse mode keeps one carry per substep
        whatever ``checkpoint`` (``"period"`` or ``"substep"``, as for ``RK4``). ``time``: the
        period's start [s], which a moving arm's plant needs (``None`` for a still arm).

        The momentum form lives only within the period: the state enters and leaves as
        ``PlantState``, so controllers and sensors see the same interface as under RK4."""
        check_checkpoint(checkpoint)
        h = period / substeps
        tableau, rotating = self.tableau, self.kernel != "reference"
        starts = None if time is None else time + h * jnp.arange(substeps, dtype=jnp.float64)

        @functools.partial(jax.checkpoint, prevent_cse=False)
        def body(m, t):
            return ark_step(m, fu, model, h, tableau=tableau, rotating=rotating, t=t), None

        return from_momentum(jax.lax.scan(body, to_momentum(s, model), starts, length=substeps)[0], model)


@jax.tree_util.register_static
@dataclasses.dataclass(frozen=True, kw_only=True)
class ARK3(_ARK):
    """Kennedy & Carpenter's ARK3(2)4L[2]SA (order 3, four stages, three implicit; the one
    ``SWEEP_NUMERICS`` uses).

    Args:
        kernel: ``"fast"`` (default: ``cos/sin`` carried through the stages by small-angle
            rotations) or ``"reference"`` (evaluated at every stage); equal to round-off.
    """

    method: ClassVar[str] = "ark3"
    tableau: ClassVar[Tableau] = ARK324


@jax.tree_util.register_static
@dataclasses.dataclass(frozen=True, kw_only=True)
class ARK4(_ARK):
    """Kennedy & Carpenter's ARK4(3)6L[2]SA (order 4, six stages, five implicit).

    Args:
        kernel: ``"fast"`` (default: ``cos/sin`` carried through the stages by small-angle
            rotations) or ``"reference"`` (evaluated at every stage); equal to round-off.
    """

    method: ClassVar[str] = "ark4"
    tableau: ClassVar[Tableau] = ARK436
