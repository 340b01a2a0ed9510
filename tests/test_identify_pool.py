"""Several recordings through sweeps/estimate_recording.py --model (armimp_jax.study.recording.identify_pool):
a config's [recordings] (postures and the robot alone) becomes one Recording each, at the
recording's own rest position; bad lists get one line; slow: the script's pooled table. And
``aj.identify`` with a list of ``Recording``: every refusal, in one line, before long work."""

import contextlib
import functools
import importlib.util
import io
import json
import pathlib
import types

import jax
import numpy as np
import pandas as pd
import pytest
from helpers import write_toml

import armimp_jax as aj
from armimp_jax import presets
from armimp_jax.study.recording import identify_pool
from armimp_jax.study.recording import identify_recording as idr

ROOT = pathlib.Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("estimate_recording_pool", ROOT / "sweeps" / "estimate_recording.py")
script = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(script)
HEADER = "f_delta_x,f_delta_y,x,y,fh_x,fh_y"
NUM = aj.Numerics(solver=aj.solvers.RK4(), substeps=2)


def _write(path, f, x, fh):
    np.savetxt(path, np.column_stack([f, x, fh]), delimiter=",", fmt="%.17g", header=HEADER, comments="")
    return path


def _config(files, groups, alone, free=("arm.stiffness",), shared=None):
    arm = presets.arm(2)
    recordings = {"files": files, "groups": groups, "alone": alone}
    if shared is not None:
        recordings["shared"] = list(shared)
    return {
        "controller": {"type": "pd"},
        "arm": {
            "mass": np.asarray(arm.mass).tolist(),
            "damping": np.asarray(arm.damping).tolist(),
            "stiffness": (0.8 * np.asarray(arm.stiffness)).tolist(),
            "endpoint": np.asarray(arm.endpoint).tolist(),
        },
        "friction": {"tau_c": 0.0, "tau_s": 0.0, "sigma2": 0.0},  # aj.NO_FRICTION: no viscous term either
        "identify": {"free": list(free), "draws": 8, "jacobian_draws": 2, "method": "rk4", "substeps": 2},
        "recordings": recordings,
    }


def _recording(tmp_path, name, endpoint, n=1024):
    x = np.tile(np.asarray(endpoint), (n, 1))
    return _write(tmp_path / name, np.zeros((n, 2)), x, np.zeros((n, 2)))


def test_each_recording_is_a_model_at_its_own_rest_position_and_the_robot_alone_has_no_arm(tmp_path):
    ends = {"1": presets.location_endpoint(1), "2": presets.location_endpoint(2)}
    for g, e in ends.items():
        _recording(tmp_path, f"p{g}.csv", e)
    _recording(tmp_path, "alone.csv", ends["2"])
    path = write_toml(
        tmp_path / "pool.toml", _config(["p1.csv", "p2.csv", "alone.csv"], ["1", "2", "alone"], ["alone"])
    )
    config = idr.read_identify_config(path)
    listed = identify_pool.files(config, path)
    assert [(p.name, g) for p, g in listed] == [("p1.csv", "1"), ("p2.csv", "2"), ("alone.csv", "alone")]
    from armimp_jax.study.recording import recording

    loaded = [(g, recording.load_recording(p)) for p, g in listed]
    recs = identify_pool.build_recordings(config, loaded, str(path))
    assert [r.group for r in recs] == ["1", "2", "alone"]
    for r, (g, e) in zip(recs, [("1", ends["1"]), ("2", ends["2"]), ("alone", ends["2"])], strict=True):
        np.testing.assert_allclose(np.asarray(r.model.x0), np.asarray(e), rtol=0, atol=1e-12)  # through q0
    np.testing.assert_array_equal(np.asarray(recs[2].model.arm.stiffness), 0.0)
    np.testing.assert_allclose(np.asarray(recs[0].model.arm.stiffness), 0.8 * np.asarray(presets.arm(2).stiffness))


@pytest.mark.parametrize(
    "change, message",
    [
        (dict(files=[]), r"\[recordings\] files must list at least one recording"),
        (dict(groups=["1"]), r"groups must name one group per file: 2 files, 1 groups"),
        (dict(alone=["nobody"]), r"alone names 'nobody', which is no group; groups: a, b"),
    ],
)
def test_a_bad_list_of_recordings_is_refused_in_one_line(tmp_path, change, message):
    config = _config(["a.csv", "b.csv"], ["a", "b"], [])
    config["recordings"].update(change)
    path = write_toml(tmp_path / "pool.toml", config)
    with pytest.raises(ValueError, match=message):
        identify_pool.files(idr.read_identify_config(path), path)


def test_the_script_wants_a_recording_or_a_list_of_them_not_both(tmp_path, capsys):
    _recording(tmp_path, "a.csv", presets.location_endpoint(2))
    pooled = write_toml(tmp_path / "pool.toml", _config(["a.csv"], ["a"], []))
    single = write_toml(
        tmp_path / "one.toml", {k: v for k, v in _config(["a.csv"], ["a"], []).items() if k != "recordings"}
    )
    out = str(tmp_path / "out")
    assert script.main([str(tmp_path / "a.csv"), "--fs", "1000", "--model", str(pooled), "--out", out]) == 2
    assert "lists its recordings in [recordings]: give no RECORDING" in capsys.readouterr().err
    assert script.main(["--fs", "1000", "--model", str(single), "--out", out]) == 2
    assert "has no [recordings]: give the RECORDING to identify" in capsys.readouterr().err
    assert script.main(["--fs", "1000", "--model", str(pooled), "--out", out, "--sensitivity", "10"]) == 2
    assert "--sensitivity takes one RECORDING, not a [recordings] list" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def _classical(arm, sign=1.0):
    """What the printout reads of a classical fit (``classical_fit``'s second item): ``arm``'s
    matrices times ``sign``."""
    zero = np.zeros((2, 2))
    fields = {n: sign * np.asarray(getattr(arm, n)) for n in ("mass", "damping", "stiffness")}
    fields.update(delay=0.0, vaf_overall=99.0)
    return None, types.SimpleNamespace(**fields, mass_se=zero, damping_se=zero, stiffness_se=zero)


def test_the_pooled_printout_shows_each_recordings_classical_value_vaf_whiteness_and_warnings():
    """Per recording, its classical value beside its group's arm, its VAF and whiteness under its
    name, and the single route's warnings about it (prefixed with it): coloured residuals, a
    classical fit no human arm gives; none for the robot alone's force, which has no variance."""
    from armimp_jax._identification.result import Identification, RecordingFit
    from armimp_jax.study.recording import recording_report

    k1, k2 = (np.asarray(presets.arm(i).stiffness) for i in (1, 2))
    trials = [aj.make_trial(aj.PD(), arm=presets.arm(i), friction=aj.NO_FRICTION) for i in (1, 2)] + [
        aj.make_trial(aj.PD(), arm=aj.presets.no_arm(presets.location_endpoint(2)), friction=aj.NO_FRICTION)
    ]
    white, coloured, none = [0.3, 0.2, 0.4, 0.5], [1e-5, 0.2, 0.4, 0.5], [0.3, 0.2, np.nan, np.nan]
    fits = [
        RecordingFit(g, t, np.array([99.0, 98.5]), f, np.array(w), np.zeros(2), None)
        for g, t, f, w in zip(
            ("1", "2", "alone"), trials, (np.array([95.0, 96.0]),) * 2 + (np.full(2, np.nan),), (coloured, white, none)
        )
    ]
    values = {"arm.stiffness@1": k1, "arm.stiffness@2": k2, "robot.inertia": np.asarray(aj.presets.MIT_MANUS.inertia)}
    se = {name: 0.01 * np.abs(v) for name, v in values.items()}
    res = Identification(
        values,
        se,
        np.eye(11),
        [],
        True,
        "",
        True,
        [],
        {},
        "welch",
        0.1,
        3,
        [],
        8,
        {},
        *fits[0][2:6],
        None,
        trials[0],
        1.0,
        0.1,
        tuple(fits),
    )
    classical = [_classical(presets.arm(1), 1.02), _classical(presets.arm(2), -1.0), None]  # -F_h recorded at 2
    names = ["p1.csv", "p2.csv", "alone.csv"]
    loaded = [(f.group, {"x": np.tile(np.asarray(f.trial.x0), (4, 1))}) for f in fits]
    warnings = idr.pooled_warnings(res, names, loaded, classical)
    lines = recording_report.pooled_report(res, names, classical, warnings)
    beside = f"{k1[0, 0]:10.4g} +- {0.01 * k1[0, 0]:.3g}   (classical {1.02 * k1[0, 0]:.4g})"
    assert f"  arm.stiffness[0,0] (group 1) [N/m]: {beside}" in lines
    assert any(line.startswith("  robot.inertia[0] (shared) [kg m^2]: ") and "classical" not in line for line in lines)
    assert "recording p2.csv (group 2): VAF [%]: x 99.00, y 98.50, fh_x 95.00, fh_y 96.00" in lines
    assert (
        "recording alone.csv (group alone): residual whiteness (Ljung-Box p): x 0.3, y 0.2, fh_x nan, fh_y nan" in lines
    )
    said = [line for line in lines if line.startswith("WARNING: ")]
    assert len(said) == 2 and said[0].startswith(
        "WARNING: recording p1.csv (group 1): the residuals are not white: x (p = 1e-05)"
    )
    assert said[1].startswith(
        "WARNING: recording p2.csv (group 2): the classical fit: implausible for a human arm: Mxx -0.79 kg"
    )
    assert said[1].split("most likely first: ")[1].startswith("the force's sign") and "Kxx -31.53" in said[1]
    doc = identify_pool.fits(res, classical)
    np.testing.assert_array_equal(doc[1]["classical"]["stiffness"], -k2)
    assert doc[2]["classical"] is None


@pytest.mark.slow  # about 60 s cold: a pooled identification of three recordings
def test_the_script_identifies_two_postures_and_the_robot_alone_in_one_table(tmp_path):
    """Noise-free PD recordings at locations 1 and 2 (each its own stiffness) and of the robot
    alone, the robot's link inertias 15% above the config's: the table holds each posture's
    stiffness and one shared inertia, each the truth."""
    robot = aj.Robot(inertia=1.15 * np.asarray(aj.presets.MIT_MANUS.inertia))
    f = aj.perturbation(jax.random.key(4), 2000, presets.perturbation_peak(1))
    a2 = presets.arm(2)  # the config's mass and damping (fixed) at both postures
    arms = {
        "1": aj.Arm(a2.mass, a2.damping, presets.arm(1).stiffness, presets.location_endpoint(1)),
        "2": a2,
        "alone": aj.presets.no_arm(presets.location_endpoint(2)),
    }
    for g, arm in arms.items():
        sim = aj.simulate(aj.make_trial(aj.PD(), arm=arm, friction=aj.NO_FRICTION, robot=robot), f, numerics=NUM)
        _write(tmp_path / f"{g}.csv", f, sim.x, sim.fh)
    config = _config([f"{g}.csv" for g in arms], list(arms), ["alone"], free=("arm.stiffness", "robot.inertia"))
    path = write_toml(tmp_path / "pool.toml", config)
    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout):
        code = script.main(["--fs", "1000", "--model", str(path), "--out", str(tmp_path / "out")])
    assert code == 0, stdout.getvalue()
    frame = pd.read_csv(tmp_path / "out" / "identification.csv", keep_default_na=False)
    for g in ("1", "2"):
        got = frame[(frame.parameter == "arm.stiffness") & (frame.group == g)].value.to_numpy().reshape(2, 2)
        np.testing.assert_allclose(got, np.asarray(arms[g].stiffness), rtol=1e-5)
    inertia = frame[frame.parameter == "robot.inertia"]
    assert list(inertia.group) == ["", "", ""]
    np.testing.assert_allclose(inertia.value.to_numpy(), np.asarray(robot.inertia), rtol=1e-5)
    doc = json.loads((tmp_path / "out" / "identification.json").read_text())
    assert doc["converged"] and [r["group"] for r in doc["recordings"]] == ["1", "2", "alone"]
    assert "(shared)" in stdout.getvalue() and "(group 2)" in stdout.getvalue()


def test_a_robot_alone_recording_does_not_see_the_force_channels_gain_or_delay():
    """The robot alone reads no hand force for the channel's gain or delay to act on: its layout
    leaves them out (its statistics of them were not finite), and keeps the offset and inertia."""
    from armimp_jax._identification import pool as pl

    end = presets.location_endpoint(2)
    sensors = aj.Sensors(force_noise=0.05, force_delay=0.001)
    human = aj.make_trial(aj.PD(), arm=presets.arm(2), friction=aj.NO_FRICTION, sensors=sensors)
    alone = aj.make_trial(aj.PD(), arm=aj.presets.no_arm(end), friction=aj.NO_FRICTION, sensors=sensors)
    f = np.zeros((1024, 2))
    free = ("arm.stiffness", "robot.inertia", "sensors.force_offset", "sensors.force_gain", "sensors.force_delay")
    recs = [aj.Recording(human, f, f, f, group="arm"), aj.Recording(alone, f, f, f, group="alone")]
    pool = pl.make_pool(recs, free, (), tuple(free[1:]))
    assert pool.layouts[0].names == free
    assert pool.layouts[1].names == ("robot.inertia", "sensors.force_offset")


@functools.cache
def _pooled_refusals():
    """``(recordings, identify's options, message)`` of each refusal of a pooled ``identify``
    (armimp_jax/_identification/identify.py and pool.py): recordings of random (not constant)
    channels, so each case trips one check alone."""
    rng = np.random.default_rng(0)
    f, x, fh = (rng.standard_normal((1024, 2)) for _ in range(3))
    end = presets.location_endpoint(2)
    sensors = aj.Sensors(force_noise=0.05)

    def trial(arm=None, friction=aj.NO_FRICTION, sensors=sensors, **kw):
        arm = presets.arm(2) if arm is None else arm
        return aj.make_trial(aj.PD(), arm=arm, friction=friction, sensors=sensors, **kw)

    human, alone, lugre = trial(), trial(aj.presets.no_arm(end)), trial(friction=aj.LuGre(0.3, 0.45))
    boxcar = trial(acquisition="interval_mean")

    def rec(model, group=None, **arrays):
        return aj.Recording(model, arrays.get("f", f), arrays.get("x", x), arrays.get("fh", fh), group)

    nan = x.copy()
    nan[123, 1] = np.nan
    k, calibrated = ("arm.stiffness",), ("arm.stiffness", "sensors.force_offset")
    two = [rec(human), rec(human)]
    return {
        "a list of Trial": ([human], {}, r"model must be a Trial \(from make_trial\) or a list of Recording, got list"),
        "an empty list": ([], {}, r"model must be a Trial \(from make_trial\) or a list of Recording, got list"),
        "arrays beside": (two, dict(f=f), "with a list of Recording, give f, x and fh in each Recording, not beside"),
        "no Trial": ([rec(human), rec("arm 2")], {}, "identify: recording 2's model must be a Trial, got str"),
        "lengths": (
            [rec(human), rec(human, x=x[:-1])],
            {},
            r"identify: recording 2: f, x and fh must have the same length, got \{'f': 1024, 'x': 1023, 'fh': 1024\}",
        ),
        "short": (
            [rec(human), rec(human, f=f[:1000], x=x[:1000], fh=fh[:1000])],
            {},
            "identify: recording 2: the record must hold at least 1024 samples, got 1000",
        ),
        "nan": ([rec(human), rec(human, x=nan)], {}, r"identify: recording 2: x holds a non-finite value.*sample 123"),
        "friction kinds": (
            [rec(human), rec(trial(friction=aj.CoulombViscous(0.06)))],
            {},
            r"every recording's robot must have the same kind of friction law \(one robot\)",
        ),
        "noise": (
            [rec(human), rec(trial(sensors=None))],
            {},
            r"every recording's model must have noise \(Sensors, VoluntaryForce\), or none",
        ),
        "sample rate": (
            [rec(human), rec(trial(period=5e-4))],
            {},
            r"identify: recording 2: a record of 1024 samples at 2000 Hz leaves .* 1 frequency bin\(s\) up to 15 Hz; "
            "it needs 3: record at least 2048 samples",
        ),
        "constant": (
            [rec(human), rec(human, x=np.ones((1024, 2)))],
            {},
            r"identify: recording 2: the recorded channel\(s\) \['x\[:, 0\]', 'x\[:, 1\]'\] are constant; nothing",
        ),
        "box-car calibration": (
            [rec(boxcar), rec(boxcar)],
            dict(free=calibrated),
            "identify: recording 1: the force channel's calibration needs acquisition 'instant'",
        ),
        "welch calibration": (
            two,
            dict(free=calibrated, statistic="welch"),
            r"identify: sensors.force_offset need the efficient statistic; use statistic='auto'",
        ),
        "shared not free": (
            two,
            dict(shared=("arm.damping",)),
            r"identify: shared names \['arm.damping'\], which are not free; free: \['arm.stiffness'\]",
        ),
        "max_steps": (two, dict(max_steps=0), "max_steps must be >= 1, got 0"),
        "friction split": (
            [rec(lugre, "a"), rec(lugre, "b")],
            dict(free=("arm.stiffness", "friction.tau_c", "friction.tau_s"), shared=("friction.tau_c",)),
            r"identify: the friction parameters must be all shared or all per group \(their maps join them\)",
        ),
        "shared arm, no arm": (
            [rec(alone, "a"), rec(alone, "b")],
            dict(shared=k),
            "identify: the arm is free but every recording is of the robot alone",
        ),
        "group mixes": (
            [rec(human, "a"), rec(alone, "a")],
            {},
            "identify: group 'a' mixes recordings with and without an arm on the handle",
        ),
        "nothing to free": (
            [rec(alone, "a"), rec(alone, "a")],
            {},
            r"identify: no recording has a parameter to free \(the arm is free, but no arm is held\)",
        ),
    }


POOLED_REFUSALS = (
    "a list of Trial",
    "an empty list",
    "arrays beside",
    "no Trial",
    "lengths",
    "short",
    "nan",
    "friction kinds",
    "noise",
    "sample rate",
    "constant",
    "box-car calibration",
    "welch calibration",
    "shared not free",
    "max_steps",
    "friction split",
    "shared arm, no arm",
    "group mixes",
    "nothing to free",
)


@pytest.mark.parametrize("case", POOLED_REFUSALS)
def test_a_pooled_identify_refuses_a_bad_list_in_one_line_before_long_work(case):
    assert set(_pooled_refusals()) == set(POOLED_REFUSALS)  # every case runs
    recordings, options, message = _pooled_refusals()[case]
    options = dict(dict(free=("arm.stiffness",)), **options)
    with pytest.raises(ValueError, match=message) as err:
        aj.identify(recordings, options.pop("f", None), **options)
    assert "\n" not in str(err.value)
