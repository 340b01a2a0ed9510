"""A lab's protocol, checked by Monte Carlo (``sweeps/bench_identify_protocol.py``, issue 47):
each case is a set of recordings drawn afresh per seed and identified in one call, started at
the truth's arm (the intervals are what is measured), and scored by the share of 95%
intervals that hold the truth, entry by entry.

The calibration cases' truth (``calibration_truth``): IMBIC at the paper's arm 2 with LuGre
0.5 / 0.75 N m, the robot's link inertias 15% above the lab's model, its viscous friction
``sigma2`` twice the model's, and the force channel 2 ms behind the position. IMBIC's desired
inertia is the lab's (the model's ``M_x(q0)``), so the controller is the same in the truth
and in the model.

- ``uncalibrated``: the human's 20 s recording, the model's robot fixed, the arm free;
- ``calibrated``: the same with two robot-alone recordings of 20 s (under PD, 10 N peak: the
  robot moves freely) pooled in, and the inertias, ``sigma2`` and the force delay free;
- ``motor-force``: ``calibrated`` on a robot without a force transducer (the hand force from
  the motor torques through the lab's model robot, ``Sensors(force_model=...)``), no delay;
- ``one-trial`` / ``four-trials``: one, then four repeated 20 s recordings of one signal at
  one posture (IMBIC, LuGre 0.5 / 0.75 N m, the arm free): the SEs should halve;
- ``four-postures``: the paper's four postures, one 20 s recording each, in one call (PD
  through LuGre 0.5 / 0.75 N m, 10 N peak), an arm per posture and ``tau_c`` shared.
- ``sensitivity`` (``sensitivity_case``, from a folder of ``sweeps/design_experiment.py``): one
  arm of the design on its designed controller and the first 20 s of its signal; each recording
  identified twice, by the true model and by one whose link inertias are 10% above the truth's
  (IMBIC's desired inertia kept, as the lab's controller). The mean paired move is the bias
  ``robot_sensitivity`` predicts (``sensitivity_prediction``: ten times the sum of its three
  inertia columns, first order).
"""

from __future__ import annotations

import dataclasses
import json
import pathlib
from collections.abc import Callable

import jax
import numpy as np

import armimp_jax as aj
from armimp_jax import presets
from armimp_jax._identification.result import bent_entries
from armimp_jax.study.sweep import coverage as cov

ARM = cov.ARM
SECONDS = 20.0
CALIBRATION = ("robot.inertia", "friction.sigma2", "sensors.force_delay")
NOISE = dict(force_noise=0.05, encoder_counts=2**18)
INERTIA_ERROR = 1.15  # the truth's link inertias over the model's
VISCOUS_ERROR = 2.0  # the truth's sigma2 over the model's
DELAY_S = 0.002  # the truth's force-channel delay [s]
DELAY_START_S = 0.001  # the calibration's starting guess of it [s]
INERTIA_OFF = 1.10  # the sensitivity case: the model's link inertias over the truth's


@dataclasses.dataclass(frozen=True)
class Case:
    """A protocol case: ``recordings(seed)`` gives ``(list of Recording, truth)`` with ``truth``
    ``{name: value}`` of every free parameter (names as ``Identification.values``' keys)."""

    free: tuple
    recordings: Callable
    shared: tuple | None = None
    off: Callable | None = None  # a trial -> the lab's wrong model of it: each seed fitted twice


def _samples() -> int:
    return int(round(SECONDS * 1000))


def _record(trial, f, key: int):
    rec = cov.record(trial, f, key)
    if bool(rec.diverged):
        raise FloatingPointError(f"the recording of key {key} diverged")
    return rec


def _lugre(viscous_factor: float = 1.0) -> aj.LuGre:
    base = aj.LuGre(0.5, 0.75)
    return aj.LuGre(0.5, 0.75, sigma2=viscous_factor * float(np.ravel(np.asarray(base.sigma2))[0]))


def calibration_truth(motor_force: bool = False):
    """``(truth, model)`` of the human's recording in the calibration cases (module docstring):
    the truth's robot, friction and force channel, and the lab's model of them (the model's
    force delay at its starting guess when the channel has one)."""
    arm = presets.arm(2)
    m_rd = np.asarray(aj.make_trial(aj.IMBIC(), arm=arm, friction=aj.NO_FRICTION).controller.m_rd)  # the lab's M_x(q0)
    robot = aj.Robot(inertia=INERTIA_ERROR * np.asarray(aj.presets.MIT_MANUS.inertia))
    sensor = dict(force_model=aj.presets.MIT_MANUS) if motor_force else dict(force_delay=DELAY_S)
    common = dict(arm=arm, voluntary=aj.VoluntaryForce(0.3, 2.0))
    friction, sensors = _lugre(VISCOUS_ERROR), aj.Sensors(**NOISE, **sensor)
    truth = aj.make_trial(aj.IMBIC(m_rd=m_rd), robot=robot, friction=friction, sensors=sensors, **common)
    start = dict(force_model=aj.presets.MIT_MANUS) if motor_force else dict(force_delay=DELAY_START_S)
    model = aj.make_trial(aj.IMBIC(m_rd=m_rd), friction=_lugre(), sensors=aj.Sensors(**NOISE, **start), **common)
    return truth, model


def _truth_values(truth, free, group=None) -> dict:
    """``coverage.truth_of``, each name carrying ``@group`` where given (a pooled answer's names)."""
    return {n if group is None else f"{n}@{group}": v for n, v in cov.truth_of(truth, free).items()}


def _calibration(seed: int, *, calibrate: bool, motor_force: bool):
    truth, model = calibration_truth(motor_force)
    f = aj.perturbation(jax.random.key(7), _samples(), presets.perturbation_peak(1))
    rec = _record(truth, f, 1000 + seed)
    if not calibrate:
        sensors = aj.Sensors(**NOISE, **({"force_model": aj.presets.MIT_MANUS} if motor_force else {}))  # no delay
        fixed = dataclasses.replace(model, sensors=sensors)
        return [aj.Recording(fixed, f, rec.x, rec.fh)], _truth_values(truth, ARM)
    recordings = [aj.Recording(model, f, rec.x, rec.fh, group="arm")]
    for i in range(2):  # the robot alone, under PD: nothing on the handle, the robot moves freely
        fa = aj.perturbation(jax.random.key(70 + i), _samples(), 10.0)
        alone = dict(arm=aj.presets.no_arm(truth.arm.endpoint), voluntary=None)
        t_alone = aj.make_trial(aj.PD(), robot=truth.robot, friction=truth.friction, sensors=truth.sensors, **alone)
        m_alone = aj.make_trial(aj.PD(), friction=model.friction, sensors=model.sensors, **alone)
        ra = _record(t_alone, fa, 2000 + 10 * seed + i)
        recordings.append(aj.Recording(m_alone, fa, ra.x, ra.fh, group="alone"))
    free = _calibration_free(motor_force)
    return recordings, _truth_values(truth, free)  # one arm group: plain names


def _calibration_free(motor_force: bool) -> tuple:
    return ARM + (CALIBRATION[:2] if motor_force else CALIBRATION)


def _trials(seed: int, count: int):
    arm = presets.arm(2)
    truth = aj.make_trial(aj.IMBIC(), arm=arm, friction=_lugre(), **cov.noise())
    f = aj.perturbation(jax.random.key(9), _samples(), presets.perturbation_peak(1))
    recs = [_record(truth, f, 3000 + 10 * seed + i) for i in range(count)]
    # one posture: one group (one arm); the same signal and model: one binding, its mean matched
    return [aj.Recording(truth, f, r.x, r.fh, group="posture 2") for r in recs], _truth_values(truth, ARM)


def _postures(seed: int):
    recordings, values = [], {}
    friction = _lugre()
    for loc in presets.LOCATIONS:
        truth = aj.make_trial(aj.PD(), arm=presets.arm(loc), friction=friction, **cov.noise())
        f = aj.perturbation(jax.random.key(20 + loc), _samples(), 10.0)
        rec = _record(truth, f, 4000 + 10 * seed + loc)
        recordings.append(aj.Recording(truth, f, rec.x, rec.fh, group=f"posture {loc}"))
        values |= _truth_values(truth, ARM, f"posture {loc}")
    values |= _truth_values(truth, ("friction.tau_c",))
    return recordings, values


CASES = {
    "uncalibrated": Case(ARM, lambda s: _calibration(s, calibrate=False, motor_force=False)),
    "calibrated": Case(_calibration_free(False), lambda s: _calibration(s, calibrate=True, motor_force=False)),
    "motor-force": Case(_calibration_free(True), lambda s: _calibration(s, calibrate=True, motor_force=True)),
    "one-trial": Case(ARM, lambda s: _trials(s, 1)),
    "four-trials": Case(ARM, lambda s: _trials(s, 4)),
    "four-postures": Case(ARM + ("friction.tau_c",), _postures),
}


def designed(folder) -> tuple[list, np.ndarray]:
    """``(trials, signal)`` of a ``design_experiment.py`` folder: each arm's trial on the designed
    controller (``design.json``'s, as its config builds it) and the perturbation ``(N, 2)`` [N]."""
    from armimp_jax.study.design.design_experiment import paper_arm
    from armimp_jax.study.schema.config import build_trial

    folder = pathlib.Path(folder)
    doc = json.loads((folder / "design.json").read_text())
    config = doc["settings"]["config"]
    config = dict(config, controller=doc.get("controller", config["controller"]))  # a bound design's gains
    robust = config["design"]["robust"] or [None]
    trials = [build_trial(config, arm=None if loc is None else paper_arm(loc)) for loc in robust]
    return trials, np.load(folder / "perturbation.npz")["f_delta"]


def _digest(folder) -> str:
    """The design's files' SHA-256: a rerun of the design into the same folder is another study."""
    import hashlib

    h = hashlib.sha256()
    for name in ("design.json", "perturbation.npz"):
        h.update((pathlib.Path(folder) / name).read_bytes())
    return h.hexdigest()


def _inertia_off(trial):
    robot = dataclasses.replace(trial.robot, inertia=INERTIA_OFF * np.asarray(trial.robot.inertia))
    return dataclasses.replace(trial, robot=robot)  # the controller as resolved: the lab's


def sensitivity_case(folder, arm: int = 0) -> Case:
    """The ``sensitivity`` case of a design folder's arm ``arm`` (module docstring)."""
    trials, signal = designed(folder)
    if not 0 <= arm < len(trials):
        last = len(trials) - 1
        raise ValueError(f"the design in {folder} has {len(trials)} arm(s): --design-arm must be 0 to {last}")
    truth, f = trials[arm], np.asarray(signal[: _samples()])

    def recordings(seed):
        rec = _record(truth, f, 5000 + seed)
        return [aj.Recording(truth, f, rec.x, rec.fh)], _truth_values(truth, ARM)

    return Case(ARM, recordings, off=_inertia_off)


def sensitivity_prediction(folder, arm: int = 0, *, draws: int = 64) -> dict:
    """``robot_sensitivity`` at the ``sensitivity`` case's truth and signal: per arm entry the
    bias of link inertias ``INERTIA_OFF`` times the truth's (first order) and the SE."""
    trials, signal = designed(folder)
    s = aj.experiment.robot_sensitivity(trials[arm], signal[: _samples()], free=ARM, robot="robot.inertia", draws=draws)
    bias = 100.0 * (INERTIA_OFF - 1.0) * s.bias_per_percent.sum(axis=1)
    return dict(labels=s.arm_labels, bias=bias.tolist(), se=s.se.tolist(), table=s.table())


def _identify(c: Case, recordings, options):
    if len(recordings) == 1:
        r = recordings[0]
        return aj.identify(r.model, r.f, r.x, r.fh, **options)
    return aj.identify(recordings, shared=c.shared, **options)


def one(case: str, seed: int, *, draws: int = 64, cases=None) -> dict:
    """One seed of ``case`` (of ``cases``, default ``CASES``): its recordings identified in one
    call (the seed keys the draws), with each free entry's estimate, SE and truth, as plain
    lists; a case with an ``off`` model adds that fit's values (``values_off``)."""
    c = (CASES if cases is None else cases)[case]
    recordings, truth = c.recordings(seed)
    options = dict(free=c.free, draws=draws, key=jax.random.key(seed))
    res = _identify(c, recordings, options)
    extra = {}
    if c.off is not None:  # the same recordings and draws, the lab's wrong model
        wrong = [r._replace(model=c.off(r.model)) for r in recordings]
        off = _identify(c, wrong, options)
        extra = dict(
            converged_off=bool(off.converged), values_off={n: np.asarray(v).tolist() for n, v in off.values.items()}
        )
    return extra | dict(
        seed=seed,
        diverged=False,
        converged=bool(res.converged),
        reliable=bool(res.intervals_reliable),
        message=res.message,
        warnings=list(res.warnings),
        spread_ratio={k: v for k, v in res.spread_ratio.items() if k.startswith("arm.")},
        disagreements=[d._asdict() for d in res.disagreements],
        time_s=float(res.time_s),
        iterations=int(res.iterations),
        values={n: np.asarray(v).tolist() for n, v in res.values.items()},
        se={n: np.asarray(v).tolist() for n, v in res.se.items()},
        truth={n: np.asarray(v).tolist() for n, v in truth.items()},
    )


def summary(rows: list[dict]) -> dict:
    """Per parameter: coverage of the 95% intervals entry by entry, the SD of
    ``z = (estimate - truth) / SE``, and the mean SE; over the arm's entries and over the rest."""
    ok = [r for r in rows if not r["diverged"] and r["converged"]]
    out = dict(recordings=len(rows), converged=len(ok), parameters={})
    if len(ok) < 2:
        return out
    arm_hits, other_hits = [], []
    for n in ok[0]["values"]:
        e = np.array([r["values"][n] for r in ok])
        s = np.array([r["se"][n] for r in ok])
        t = np.asarray(ok[0]["truth"][n])
        z = (e - t) / s
        hit = np.abs(z) <= cov.Z95
        (arm_hits if n.startswith("arm.") else other_hits).append(hit.reshape(len(ok), -1))
        out["parameters"][n] = dict(
            coverage=hit.mean(axis=0).ravel().tolist(),
            sd_z=z.std(axis=0, ddof=1).ravel().tolist(),
            mean_z=z.mean(axis=0).ravel().tolist(),
            mean_se=s.mean(axis=0).ravel().tolist(),
        )
    out["coverage_arm"] = float(np.concatenate(arm_hits, axis=1).mean()) if arm_hits else None
    out["coverage_other"] = float(np.concatenate(other_hits, axis=1).mean()) if other_hits else None
    out["mean_time_s"] = float(np.mean([r["time_s"] for r in ok]))
    out["warned"] = float(np.mean([bool(r["warnings"]) for r in ok]))
    if all(r.get("spread_ratio") for r in ok):  # records from before 2.4 (or without friction) carry none
        out["bent"] = float(np.mean([bool(bent_entries(r["spread_ratio"])) for r in ok]))
        out["spread_ratio_median"] = {
            k: float(np.median([r["spread_ratio"][k] for r in ok])) for k in ok[0]["spread_ratio"]
        }
    return out


def paired_summary(rows: list[dict], prediction: dict) -> dict:
    """The ``sensitivity`` case: per arm entry the mean paired move (wrong model less right) over
    the seeds both fits converged on, its standard error, the predicted bias and their ratio
    (where the move is measurable: more than three of its standard errors)."""
    ok = [r for r in rows if not r["diverged"] and r["converged"] and r["converged_off"]]
    out = dict(recordings=len(rows), both_converged=len(ok), entries={})
    if len(ok) < 2:
        return out
    moves = np.array(
        [np.concatenate([np.ravel(np.subtract(r["values_off"][n], r["values"][n])) for n in ARM]) for r in ok]
    )
    mean, sem = moves.mean(axis=0), moves.std(axis=0, ddof=1) / np.sqrt(len(ok))
    for i, label in enumerate(prediction["labels"]):
        predicted = prediction["bias"][i]
        measurable = abs(mean[i]) > 3 * sem[i]
        out["entries"][label] = dict(
            measured=float(mean[i]),
            measured_se=float(sem[i]),
            predicted=float(predicted),
            in_se=float(predicted / prediction["se"][i]),
            ratio=float(predicted / mean[i]) if measurable else None,
        )
    return out


def study(
    cases,
    seeds: int,
    out,
    *,
    draws: int = 64,
    design=None,
    design_arm: int = 0,
    catalogue=None,
    catalogue_settings=None,
    console=None,
) -> dict:
    """Run (or resume) ``cases`` x ``seeds`` in run folder ``out`` on the study engine; per case
    ``{seeds: rows, summary}``, also written to ``out/protocol.json`` with the settings. The
    ``sensitivity`` case needs ``design`` (a ``design_experiment.py`` folder) and its arm.
    ``catalogue``: the cases by name (default ``CASES``; ``armimp_bench.entrywise.cells``', say), with
    ``catalogue_settings``, what describes them (the run's settings)."""
    from armimp_jax.study.runs.results import atomic_write_json, stamped

    described = dict(seconds=SECONDS) if catalogue is None else dict(cases=catalogue_settings)
    settings = dict(draws=draws, **described)
    known = dict(CASES if catalogue is None else catalogue)
    if "sensitivity" in cases:
        digest = _digest(design)
        settings.update(design=str(design), design_digest=digest, design_arm=design_arm, inertia_off=INERTIA_OFF)
        known["sensitivity"] = sensitivity_case(design, design_arm)

    def report(name, row):
        steps = f"{row['iterations']} steps, converged {row['converged']}"
        return f"  {name} seed {row['seed']}: {row['time_s']:.1f} s, {steps}"

    def finish(run, rows):
        done = {name: dict(seeds=rs, summary=summary(rs)) for name, rs in rows.items()}
        if "sensitivity" in done:
            prediction = sensitivity_prediction(design, design_arm, draws=draws)
            done["sensitivity"].update(prediction=prediction, paired=paired_summary(rows["sensitivity"], prediction))
        atomic_write_json(run.path / "protocol.json", dict(settings=stamped(settings), cases=done))
        return done

    def row(case, _f, _name, seed):
        return one(case, seed, draws=draws, cases=known)

    spec = cov.Recordings("protocol", settings, list(cases), range(seeds), lambda c: (c, None), row, report)
    return cov.run_recordings(spec, out, console=console, finish=finish).finished
