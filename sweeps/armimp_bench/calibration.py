"""What ``sweeps/bench_calibrate.py`` measures: ``calibrate_robot`` and ``calibrate_force`` on the
protocol's calibration case (``armimp_bench.protocol.calibration_truth``: the robot's link inertias 15%
above the lab's model, LuGre 0.5 / 0.75 N m with its viscous friction twice the model's, force
noise 0.05 N, 2^18-count encoders), two robot-alone recordings of 20 s under PD (10 N peak).

- ``coverage``: over seeds, the share of 95% intervals holding the truth: the inertias against
  the truth's, the friction against the static law's best approximation of LuGre (the least
  squares of LuGre's torque on ``sign(v)`` and ``v`` over the samples the calibration keeps:
  ``best_static``), the force offset against zero; and what that approximation costs (LuGre's
  torque less it, RMS, where kept and where left out). Under PD with no one on the handle the
  loop holds no random noise (the force noise only reaches the record), so each seed draws
  its own perturbations: the spread is over excitations, as a lab's repeated calibrations'.
- ``force_coverage``: five known loads, each read for 1 s at 1 kHz, over draws.
- ``speed``: the calibration's wall time for two 20 s recordings, first call and warm.
- ``arm_study`` (``arm.py``): the arm identified through the calibration, resumable.
"""

from __future__ import annotations

import dataclasses
import functools
import time

import jax
import numpy as np

import armimp_jax as aj
from armimp_bench import protocol as pr
from armimp_jax._calibration import idim
from armimp_jax._calibration.robot_calibration import MIN_RATE
from armimp_jax.study.sweep import coverage as cov

SECONDS = 20.0
PEAK = 10.0  # [N] the robot-alone perturbation's peak (protocol.py's)
RECORDINGS = 2
KEY_BASE = 70_000  # perturbation keys KEY_BASE + RECORDINGS seed + i; noise keys NOISE_BASE + the same
NOISE_BASE = 80_000
LOADS = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [0.0, 1.0], [0.0, 2.0]]) * 9.81  # 0, 1, 2 kg hung [N]
FORCE_GAIN = np.array([1.05, 0.95])
FORCE_OFFSET = np.array([0.2, -0.1])  # [N]
FORCE_SAMPLES = 1000  # one second of readings per load at 1 kHz


@functools.cache
def _alone():
    """``(truth trial, lab's model robot)`` of the robot alone under PD, the protocol's truth."""
    truth, _ = pr.calibration_truth()
    alone = dict(arm=aj.presets.no_arm(truth.arm.endpoint), voluntary=None)
    trial = aj.make_trial(aj.PD(), robot=truth.robot, friction=truth.friction, sensors=truth.sensors, **alone)
    return trial, aj.presets.MIT_MANUS


def alone_recordings(seed: int, seconds: float = SECONDS):
    """The ``RECORDINGS`` robot-alone simulations of ``seed`` (``SimResult``s, each its own
    perturbation and noise)."""
    trial, _ = _alone()
    n = int(round(seconds / trial.period))
    out = []
    for i in range(RECORDINGS):
        k = RECORDINGS * seed + i
        f = aj.perturbation(jax.random.key(KEY_BASE + k), n, PEAK)
        rec = cov.record(trial, f, NOISE_BASE + k)
        if bool(rec.diverged):
            raise FloatingPointError(f"the robot-alone recording {k} diverged")
        out.append(jax.tree.map(np.asarray, rec))
    return out


def as_recordings(sims) -> list:
    """``RobotRecording``s of simulations: what a lab records (hand position, command, force)."""
    return [aj.RobotRecording(x=s.x, command=s.fu, fh=s.fh) for s in sims]


def best_static(sims, cal) -> dict:
    """The static law's best approximation of the truth's LuGre over the samples the calibration
    keeps (``sign(v)`` and ``v`` by least squares per joint, ``v`` the true rate), and what it
    costs: LuGre's torque less it, RMS [N m], over the kept samples and the rest."""
    friction = _alone()[0].friction
    columns, torques, keeps = [], [], []
    for s in sims:
        v = idim.rates(s.q, 1e-3)[0]
        tau = _lugre_torque(friction, v, s.z)
        taps = idim.fir(cal.cutoff, 1e3)
        keeps.append(idim.kept(idim.zero_phase(taps, v), MIN_RATE, idim.support(taps)))
        columns.append(np.stack([np.sign(v), v], axis=-1))
        torques.append(tau)
    col, tau, keep = (np.concatenate(a) for a in (columns, torques, keeps))
    coef = np.array([np.linalg.lstsq(col[keep[:, j], j], tau[keep[:, j], j], rcond=None)[0] for j in range(2)])
    fit = np.einsum("njp,jp->nj", col, coef)
    miss = tau - fit
    rms = [[float(np.sqrt(np.mean(miss[m[:, j], j] ** 2))) for j in range(2)] for m in (keep, ~keep)]
    return dict(tau_c=coef[:, 0].tolist(), viscous=coef[:, 1].tolist(), rms_kept=rms[0], rms_left_out=rms[1])


def _lugre_torque(law, v, z):
    """LuGre's torque [N m] ``(N, 2)`` at rates ``v`` and bristle states ``z`` (docs/model.md section 4)."""
    tc, ts, s0, s1, s2, vs = (
        np.asarray(getattr(law, n)) for n in ("tau_c", "tau_s", "sigma0", "sigma1", "sigma2", "v_s")
    )
    g = tc + (ts - tc) * np.exp(-((v / vs) ** 2))
    zd = v - s0 * np.abs(v) * z / g
    return s0 * z + s1 * zd + s2 * v


def one_seed(seed: int) -> dict:
    """One seed: the calibration, the truth it is scored against, and the static law's cost."""
    sims = alone_recordings(seed)
    cal = aj.calibrate_robot(as_recordings(sims))
    best = best_static(sims, cal)
    trial = _alone()[0]
    truth = {
        "robot.inertia": np.asarray(trial.robot.inertia),
        "friction.tau_c": best["tau_c"],
        "friction.viscous": best["viscous"],
        "sensors.force_offset": np.zeros(2),
    }
    return dict(
        seed=seed,
        values={n: np.asarray(v).tolist() for n, v in cal.values.items()},
        se={n: np.asarray(v).tolist() for n, v in cal.se.items()},
        truth={n: np.asarray(v).tolist() for n, v in truth.items()},
        best=best,
        kept=cal.kept_fraction.tolist(),
        time_s=cal.time_s,
        warnings=cal.warnings,
    )


def coverage(seeds: int, progress=None) -> dict:
    """``{rows, summary}`` over ``seeds`` seeds (``one_seed``); ``summary`` per entry: coverage,
    mean and SD of ``z``, the mean SE, and the static law's cost."""
    rows = []
    for s in range(seeds):
        rows.append(one_seed(s))
        if progress:
            progress(rows[-1])
    return dict(rows=rows, summary=coverage_summary(rows))


def coverage_summary(rows) -> dict:
    out = {}
    for name in rows[0]["values"]:
        e, s, t = (np.array([r[k][name] for r in rows]) for k in ("values", "se", "truth"))
        z = (e - t) / s
        out[name] = dict(
            coverage=(np.abs(z) <= cov.Z95).mean(axis=0).tolist(),
            mean_z=z.mean(axis=0).tolist(),
            sd_z=z.std(axis=0, ddof=1).tolist(),
            mean_se=s.mean(axis=0).tolist(),
        )
    best = [r["best"] for r in rows]
    out["static_law"] = {
        k: np.mean([b[k] for b in best], axis=0).tolist() for k in ("tau_c", "viscous", "rms_kept", "rms_left_out")
    }
    out["kept"] = np.mean([r["kept"] for r in rows], axis=0).tolist()
    out["warned"] = float(np.mean([bool(r["warnings"]) for r in rows]))
    return out


def force_coverage(draws: int = 200, *, noise: float = 0.05, seed: int = 0) -> dict:
    """``calibrate_force`` over ``draws``: the share of its 95% (Student t) intervals holding the
    truth, gain and offset per axis, and the mean SE."""
    rng = np.random.default_rng(seed)
    hits, se = [], []
    for _ in range(draws):
        readings = (
            FORCE_GAIN * LOADS[:, None, :] + FORCE_OFFSET + noise * rng.standard_normal((len(LOADS), FORCE_SAMPLES, 2))
        )
        cal = aj.calibrate_force(LOADS, readings)
        row = []
        for name, true in (("sensors.force_gain", FORCE_GAIN), ("sensors.force_offset", FORCE_OFFSET)):
            low, high = cal.interval(name)
            row.append((low <= true) & (true <= high))
        hits.append(np.concatenate(row))
        se.append(np.concatenate([cal.se["sensors.force_gain"], cal.se["sensors.force_offset"]]))
    return dict(
        draws=draws, labels=cal.labels, coverage=np.mean(hits, axis=0).tolist(), mean_se=np.mean(se, axis=0).tolist()
    )


def speed(repeats: int = 5) -> dict:
    """``calibrate_robot``'s wall time [s] for two 20 s recordings: the first call in this process
    (its inverse kinematics compiled) and the median of ``repeats`` more."""
    recordings = as_recordings(alone_recordings(0))
    times = []
    for _ in range(repeats + 1):
        t0 = time.perf_counter()
        aj.calibrate_robot(recordings)
        times.append(time.perf_counter() - t0)
    return dict(first_s=times[0], median_s=float(np.median(times[1:])), repeats=repeats)


def coverage_table(summary: dict) -> str:
    """The coverage study's Markdown table, per entry."""
    lines = ["| entry | coverage | mean z | SD of z | mean SE |", "|---|---|---|---|---|"]
    for name, s in summary.items():
        if name in ("static_law", "kept", "warned"):
            continue
        for i, c in enumerate(s["coverage"]):
            cells = f"{c:.2f} | {s['mean_z'][i]:+.2f} | {s['sd_z'][i]:.2f} | {s['mean_se'][i]:.2g}"
            lines.append(f"| {name}[{i}] | {cells} |")
    return "\n".join(lines)


# The arm through the calibration (``arm_study``): the protocol's human recording (IMBIC, arm 2,
# LuGre 0.5 / 0.75 N m, the truth's robot 15% heavier, its sigma2 twice, the force 2 ms late) and
# this seed's robot-alone pair, identified four ways. The force channel's delay is no part of the
# robot's calibration: the lab measures it apart (a tap on the handle), so every model has the
# truth's 2 ms (with it free from 1 ms the case was fragile on seed 0 with the true robot too: the
# delay barely told, the fitted model diverging). Every variant frees the force channel's offset
# (calibrated: from the robot alone's value): held at the robot alone's value, 1 SE (0.25 mN) off
# moved the arm's stiffness by 20-36 SE on seed 0, while the person's recording tells the offset to
# 0.3 uN (docs/identification.md section 4d).
VARIANTS = ("calibrated", "nominal", "true", "motor-force")
# The motor-force variant subtracts the calibration's static law from the motor torques (without
# it IMBIC reads the friction as the person's force and cannot cancel it: the joints stuck for
# 84-86% of the record, against 4-5% with a transducer), smoothed at LuGre's Stribeck velocity,
# which the lab takes as known like LuGre's other shape parameters.
MOTOR_V_S = float(np.ravel(aj.LuGre(0.5, 0.75).v_s)[0])
FREE = pr.ARM + ("sensors.force_offset",)


def _arm_case(variant: str, seed: int):
    """``(model, recording, f, free, calibration, truth values)`` of one variant and seed."""
    from armimp_jax import presets

    motor = variant == "motor-force"
    truth, model = pr.calibration_truth(motor)
    cal = None
    if variant in ("calibrated", "motor-force"):
        cal = aj.calibrate_robot(as_recordings(alone_recordings(seed)))
    if motor:  # the hand force through the calibrated robot, less its calibrated static friction law
        sensors = aj.Sensors(**pr.NOISE, force_model=cal.robot, force_friction=cal.friction(v_s=MOTOR_V_S))
        truth = dataclasses.replace(truth, sensors=sensors)
    else:  # the delay measured apart
        sensors = aj.Sensors(**pr.NOISE, force_delay=pr.DELAY_S)
    model = dataclasses.replace(model, sensors=sensors)
    free = FREE  # the calibration's robot parameters are held at its values and carried; the offset estimated
    if variant == "true":  # the lab knows its robot: the truth's inertia and friction
        model = dataclasses.replace(model, robot=truth.robot, friction=truth.friction)
    f = aj.perturbation(jax.random.key(7), int(round(SECONDS * 1000)), presets.perturbation_peak(1))
    rec = pr._record(truth, f, 1000 + seed)
    return model, rec, f, free, cal, pr._truth_values(truth, free)


def arm_row(variant: str, seed: int, *, draws: int = 64) -> dict:
    """One recording of ``variant`` identified (``protocol.one``'s row)."""
    model, rec, f, free, cal, truth = _arm_case(variant, seed)
    res = aj.identify(model, f, rec.x, rec.fh, free=free, calibration=cal, draws=draws, key=jax.random.key(seed))
    return dict(
        seed=seed,
        diverged=False,
        converged=bool(res.converged),
        intervals_reliable=bool(res.intervals_reliable),
        message=res.message,
        warnings=list(res.warnings),
        time_s=float(res.time_s),
        iterations=int(res.iterations),
        values={n: np.asarray(v).tolist() for n, v in res.values.items()},
        se={n: np.asarray(v).tolist() for n, v in res.se.items()},
        truth={n: np.asarray(v).tolist() for n, v in truth.items()},
        spread_ratio=dict(res.spread_ratio),
    )


def arm_study(variants, seeds: int, out, *, draws: int = 64) -> dict:
    """Run (or resume) ``variants`` x ``seeds`` in run folder ``out`` on the study engine; per
    variant ``{seeds: rows, summary}`` (``protocol.summary``: coverage, SD of z), and the arm's
    mean SEs over the true robot's where both ran (what the calibration's uncertainty costs)."""

    def report(name, row):
        steps = f"{row['iterations']} steps, converged {row['converged']}"
        return f"  {name} seed {row['seed']}: {row['time_s']:.1f} s, {steps}"

    def finish(run, rows):
        done = {name: dict(seeds=rs, summary=pr.summary(rs)) for name, rs in rows.items()}
        true = done.get("true", {}).get("summary", {}).get("parameters", {})
        for name, d in done.items():
            mine = d["summary"].get("parameters", {})
            d["se_over_true"] = {
                n: np.divide(mine[n]["mean_se"], true[n]["mean_se"]).tolist() for n in pr.ARM if n in mine and n in true
            }
        return done

    settings = dict(draws=draws, seconds=SECONDS, study="calibration-arm", free=list(FREE), motor_v_s=MOTOR_V_S)
    spec = cov.Recordings(
        "calibration-arm",
        settings,
        list(variants),
        range(seeds),
        lambda c: (c, None),
        lambda c, _f, _n, s: arm_row(c, s, draws=draws),
        report,
    )
    return cov.run_recordings(spec, out, finish=finish).finished


def arm_table(done: dict) -> str:
    """Per variant: converged, the arm's coverage, the SD of z per arm diagonal, the SE over the
    true robot's."""
    lines = [
        "| variant | converged | arm coverage | SD of z, diagonals (M, B, K) | SE / true robot's, diagonals |",
        "|---|---|---|---|---|",
    ]
    for name, d in done.items():
        s = d["summary"]
        sd = ratio = "-"
        if "parameters" in s and s["parameters"]:
            sd = " ".join(f"{s['parameters'][n]['sd_z'][i]:.2f}" for n in pr.ARM for i in (0, 3))
        if d.get("se_over_true"):
            ratio = " ".join(f"{d['se_over_true'][n][i]:.2f}" for n in pr.ARM for i in (0, 3))
        cover = "-" if s.get("coverage_arm") is None else f"{s['coverage_arm']:.3f}"
        lines.append(f"| {name} | {s['converged']}/{s['recordings']} | {cover} | {sd} | {ratio} |")
    return "\n".join(lines)
