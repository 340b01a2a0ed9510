"""Benchmark-only baseline: the same model as a plain scalar loop, compiled with numba.

What a careful person would write by hand: one trajectory per call, RK4 with
``sin/cos`` evaluated at every stage (``cos/sin(q1 - q2)`` by angle identities), PD or
IMBIC (velocity acceleration estimate), instant acquisition. ``simulate_many`` runs one
trajectory per thread (``prange``). Used by ``bench_simulate.py``, which also checks that
it agrees with the JAX simulator.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from armimp_jax.tables import ELBOW_LINK_LENGTH as LE
from armimp_jax.tables import INERTIA_C1 as C1
from armimp_jax.tables import INERTIA_C2 as C2
from armimp_jax.tables import INERTIA_C3 as C3
from armimp_jax.tables import SHOULDER_LINK_LENGTH as LS


@njit(cache=True)
def _lugre(v, z, fr):
    g = fr[0] + (fr[1] - fr[0]) * math.exp(-((v / fr[5]) ** 2))
    zd = v - (fr[2] * abs(v) * z / g if g > 0.0 else 0.0)
    return fr[2] * z + fr[3] * zd + fr[4] * v, zd


@njit(cache=True)
def _deriv(s, fu, cq0, mh, bh, kh, fr, out):
    """State s = (q1, q2, qd1, qd2, z1, z2); writes the derivative; returns (ex, ey, xd, yd, fhx, fhy)."""
    c1, s1, c2, s2 = math.cos(s[0]), math.sin(s[0]), math.cos(s[1]), math.sin(s[1])
    cd, sd = c1 * c2 + s1 * s2, s1 * c2 - c1 * s2
    ex = LS * (c1 - cq0[0]) + LE * (c2 - cq0[2])
    ey = LS * (s1 - cq0[1]) + LE * (s2 - cq0[3])
    j11, j12, j21, j22 = -LS * s1, -LE * s2, LS * c1, LE * c2
    xd, yd = j11 * s[2] + j12 * s[3], j21 * s[2] + j22 * s[3]
    a1, a2 = s[2] * s[2], s[3] * s[3]
    jx, jy = -LS * c1 * a1 - LE * c2 * a2, -LS * s1 * a1 - LE * s2 * a2
    f0x = mh[0, 0] * jx + mh[0, 1] * jy + bh[0, 0] * xd + bh[0, 1] * yd + kh[0, 0] * ex + kh[0, 1] * ey
    f0y = mh[1, 0] * jx + mh[1, 1] * jy + bh[1, 0] * xd + bh[1, 1] * yd + kh[1, 0] * ex + kh[1, 1] * ey
    rx, ry = fu[0] - f0x, fu[1] - f0y
    t1, zd1 = _lugre(s[2], s[4], fr)
    t2, zd2 = _lugre(s[3], s[5], fr)
    b1 = j11 * rx + j21 * ry - C2 * sd * a2 - t1
    b2 = j12 * rx + j22 * ry + C2 * sd * a1 - t2
    p11, p12 = mh[0, 0] * j11 + mh[0, 1] * j21, mh[0, 0] * j12 + mh[0, 1] * j22
    p21, p22 = mh[1, 0] * j11 + mh[1, 1] * j21, mh[1, 0] * j12 + mh[1, 1] * j22
    m12 = C2 * cd
    A11, A12 = C1 + j11 * p11 + j21 * p21, m12 + j11 * p12 + j21 * p22
    A21, A22 = m12 + j12 * p11 + j22 * p21, C3 + j12 * p12 + j22 * p22
    det = A11 * A22 - A12 * A21
    qdd1, qdd2 = (A22 * b1 - A12 * b2) / det, (A11 * b2 - A21 * b1) / det
    out[0], out[1], out[2], out[3], out[4], out[5] = s[2], s[3], qdd1, qdd2, zd1, zd2
    ax, ay = j11 * qdd1 + j12 * qdd2, j21 * qdd1 + j22 * qdd2
    return ex, ey, xd, yd, mh[0, 0] * ax + mh[0, 1] * ay + f0x, mh[1, 0] * ax + mh[1, 1] * ay + f0y


@njit(cache=True)
def simulate_one(imbic, q0, x0, mh, bh, kh, fr, kp, kv, minv, mhat, f_delta, substeps, period, x_out, fh_out):
    cq0 = np.array([math.cos(q0[0]), math.sin(q0[0]), math.cos(q0[1]), math.sin(q0[1])])
    s = np.array([q0[0], q0[1], 0.0, 0.0, 0.0, 0.0])
    k1, k2, k3, k4, tmp = np.empty(6), np.empty(6), np.empty(6), np.empty(6), np.empty(6)
    fu = np.zeros(2)
    x_prev, xd_prev = x0.copy(), np.zeros(2)
    kx0 = kp @ x0
    v_prev = minv @ kx0
    h = period / substeps
    for k in range(f_delta.shape[0]):
        ex, ey, xd, yd, fhx, fhy = _deriv(s, fu, cq0, mh, bh, kh, fr, k1)
        x = np.array([x0[0] + ex, x0[1] + ey])
        xdv, fh = np.array([xd, yd]), np.array([fhx, fhy])
        x_out[k], fh_out[k] = x, fh
        if imbic:
            a = (xdv - xd_prev) / period
            v = minv @ (kx0 + f_delta[k] - fh) - (a + minv @ (kv @ xd_prev + kp @ x_prev)) + v_prev
            u = v - minv @ (kv @ xdv + kp @ x)
            fu = mhat @ u + fu - mhat @ a
            v_prev = v
        else:
            fu = f_delta[k] - kp @ (x - x0) - kv @ xdv
        x_prev, xd_prev = x, xdv
        for _ in range(substeps):
            _deriv(s, fu, cq0, mh, bh, kh, fr, k1)
            for i in range(6):
                tmp[i] = s[i] + 0.5 * h * k1[i]
            _deriv(tmp, fu, cq0, mh, bh, kh, fr, k2)
            for i in range(6):
                tmp[i] = s[i] + 0.5 * h * k2[i]
            _deriv(tmp, fu, cq0, mh, bh, kh, fr, k3)
            for i in range(6):
                tmp[i] = s[i] + h * k3[i]
            _deriv(tmp, fu, cq0, mh, bh, kh, fr, k4)
            for i in range(6):
                s[i] += (h / 6.0) * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])


@njit(parallel=True, cache=True)
def simulate_many(imbic, q0, x0, mh, bh, kh, fr, kp, kv, minv, mhat, f_delta, substeps, period, x_out, fh_out):
    for b in prange(f_delta.shape[0]):
        simulate_one(
            imbic,
            q0[b],
            x0[b],
            mh[b],
            bh[b],
            kh[b],
            fr[b],
            kp[b],
            kv[b],
            minv[b],
            mhat[b],
            f_delta[b],
            substeps,
            period,
            x_out[b],
            fh_out[b],
        )


def run(params, f_delta):
    """Run stacked ``TrialParams`` (one controller) through the numba loop; returns ``(x, fh)``."""
    # copies: arrays viewed from JAX are read-only, a different numba type (a recompile)
    p = {
        k: np.array(v, dtype=np.float64, order="C")
        for k, v in dict(
            q0=params.q0,
            x0=params.x0,
            mh=params.arm.mass,
            bh=params.arm.damping,
            kh=params.arm.stiffness,
            fr=np.stack([np.asarray(leaf) for leaf in params.friction], axis=-1),
            kp=params.gains.kp,
            kv=params.gains.kv,
            minv=params.gains.m_rd_inv,
            mhat=params.gains.mhat,
        ).items()
    }
    f_delta = np.array(f_delta, dtype=np.float64, order="C")
    x, fh = np.empty_like(f_delta), np.empty_like(f_delta)
    simulate_many(
        params.controller == "imbic",
        p["q0"],
        p["x0"],
        p["mh"],
        p["bh"],
        p["kh"],
        p["fr"],
        p["kp"],
        p["kv"],
        p["minv"],
        p["mhat"],
        f_delta,
        params.substeps,
        params.period,
        x,
        fh,
    )
    return x, fh
