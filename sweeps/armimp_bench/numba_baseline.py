"""The numba baseline of ``sweeps/numba_baseline.py`` and ``bench_simulate.py``: the same model
as a plain scalar loop (PD or IMBIC, LuGre, MIT-MANUS, RK4, instant samples, ideal sensors),
compiled with numba; imported only where numba is installed (``pip install -e '.[bench]'``).
"""

from __future__ import annotations

import math
import statistics
import time

import numpy as np
from numba import njit, prange

from armimp_jax import IMBIC, PD
from armimp_jax.presets import MIT_MANUS

# MIT-MANUS's constants, compiled into the loop
LS, LE = float(MIT_MANUS.shoulder_link), float(MIT_MANUS.elbow_link)
MIT_MANUS_INERTIA = tuple(float(c) for c in MIT_MANUS.inertia)
C1, C2, C3 = MIT_MANUS_INERTIA


@njit(cache=True)
def _lugre(v, z, fr):
    """One joint: ``fr = (tau_c, tau_s, sigma0, sigma1, sigma2, v_s)``; returns ``(tau_f, zd)``."""
    g = fr[0] + (fr[1] - fr[0]) * math.exp(-((v / fr[5]) ** 2))
    zd = v - (fr[2] * abs(v) * z / g if g > 0.0 else 0.0)
    return fr[2] * z + fr[3] * zd + fr[4] * v, zd


@njit(cache=True)
def _deriv(s, fu, cq0, mh, bh, kh, fr, out):
    """State s = (q1, q2, qd1, qd2, z1, z2), fr (2, 6) the joints' LuGre parameters; writes the
    derivative; returns (ex, ey, xd, yd, fhx, fhy)."""
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
    t1, zd1 = _lugre(s[2], s[4], fr[0])
    t2, zd2 = _lugre(s[3], s[5], fr[1])
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


def run(trials, f_delta, substeps):
    """Run stacked trials (``stack_trials``: PD or IMBIC with the velocity acceleration
    estimate, MIT-MANUS, ideal sensors, instant acquisition) driven by ``f_delta``
    ``(B, N, 2)`` through the numba loop, ``substeps`` RK4 steps per period; returns ``(x, fh)``."""
    ctrl = trials.controller
    imbic = isinstance(ctrl, IMBIC)
    if not (imbic or isinstance(ctrl, PD)):
        raise ValueError(f"numba baseline: PD or IMBIC trials only, got {type(ctrl).__name__}")
    if imbic and ctrl.accel_estimate != "velocity":
        raise ValueError("numba baseline: IMBIC with the velocity acceleration estimate only")
    if trials.acquisition != "instant" or not trials.sensors.ideal:
        raise ValueError("numba baseline: instant acquisition and ideal sensors only")
    robot = trials.robot
    for name, value, const in (
        ("shoulder_link", robot.shoulder_link, LS),
        ("elbow_link", robot.elbow_link, LE),
        ("inertia", robot.inertia, MIT_MANUS_INERTIA),
    ):
        if not np.all(np.asarray(value) == np.asarray(const)):
            raise ValueError(f"numba baseline: MIT-MANUS only (robot {name} differs)")
    fr = trials.friction
    b = np.shape(trials.q0)[0]
    zeros = np.zeros((b, 2, 2))
    # copies: arrays viewed from JAX are read-only, a different numba type (a recompile)
    p = {
        k: np.array(v, dtype=np.float64, order="C")
        for k, v in dict(
            q0=trials.q0,
            x0=trials.x0,
            mh=trials.arm.mass,
            bh=trials.arm.damping,
            kh=trials.arm.stiffness,
            fr=np.stack(
                [np.asarray(getattr(fr, f)) for f in ("tau_c", "tau_s", "sigma0", "sigma1", "sigma2", "v_s")], -1
            ),
            # IMBIC's desired stiffness and damping play PD's kp and kv
            kp=ctrl.k_rd if imbic else ctrl.kp,
            kv=ctrl.b_rd if imbic else ctrl.kv,
            minv=ctrl.m_rd_inv if imbic else zeros,
            mhat=ctrl.mhat if imbic else zeros,
        ).items()
    }
    f_delta = np.array(f_delta, dtype=np.float64, order="C")
    x, fh = np.empty_like(f_delta), np.empty_like(f_delta)
    simulate_many(
        imbic,
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
        int(substeps),
        float(trials.period),
        x,
        fh,
    )
    return x, fh


def main(args):
    """Time the numba loop on a small batch and compare it with the JAX simulator."""
    from armimp_jax import runtime

    runtime.configure(compilation_cache=False)  # compile times are measured
    import jax
    import numba

    import armimp_jax as aj
    from armimp_jax import paper

    b, n = args.batch, int(args.seconds * 1000)
    trials = aj.batch.stack_trials([paper.trial(args.controller, i % 3, 1 + i % 4) for i in range(b)])
    keys = jax.random.split(jax.random.PRNGKey(0), b)
    f_delta = np.asarray(jax.vmap(lambda k: aj.perturbation(k, n, paper.perturbation_peak(1)))(keys))
    t0 = time.perf_counter()
    run(trials, f_delta[:, :10], args.substeps)
    compile_s = time.perf_counter() - t0
    runs = []
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        x, fh = run(trials, f_delta, args.substeps)
        runs.append(time.perf_counter() - t0)
    numerics = aj.Numerics(solver=aj.solvers.RK4(kernel="reference"), substeps=args.substeps)
    ref = jax.jit(jax.vmap(lambda t, f: aj.simulate(t, f, numerics=numerics)))(trials, f_delta)
    rx, rfh = np.asarray(ref.x), np.asarray(ref.fh)
    diff_x = float(np.abs(x - rx).max() / np.abs(rx - rx[:, :1]).max())
    diff_fh = float(np.abs(fh - rfh).max() / np.abs(rfh).max())
    rate = b * n * args.substeps / statistics.median(runs) / 1e6
    print(
        f"numba {numba.get_num_threads()} threads, {args.controller} batch={b}, {args.seconds:g} s, "
        f"{args.substeps} substeps: {rate:.2f} M substeps/s (compile {compile_s:.1f} s); agrees with JAX "
        f"(reference kernel) to {diff_x:.1e} (x), {diff_fh:.1e} (fh), relative"
    )
