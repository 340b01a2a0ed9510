"""The model route of sweeps/estimate_recording.py (armimp_jax.study.recording.identify_recording): a
simulated PD recording with friction, sensor noise and a voluntary force, written to CSV and
identified from a start 15-20% off the truth; every bad config gets one line before any work."""

import contextlib
import dataclasses
import importlib.util
import io
import json
import math
import pathlib
import re
import types

import jax
import numpy as np
import pandas as pd
import pytest
from helpers import write_toml

import armimp_jax as aj
from armimp_jax import presets
from armimp_jax.study.recording import estimate_recording, recording, recording_figures
from armimp_jax.study.recording import identify_recording as idr

ROOT = pathlib.Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "sweeps" / "estimate_recording.py"
EXAMPLE = ROOT / "sweeps" / "configs" / "identify_example.toml"
_spec = importlib.util.spec_from_file_location("estimate_recording_model", SCRIPT)
script = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(script)

ARM = presets.arm(2)
TRUE_K = np.asarray(ARM.stiffness)
START = {"mass": 1.15, "damping": 0.85, "stiffness": 1.2}  # the start: the truth times these
N_SAMPLES = 3000  # 3 s at 1 kHz
SUBSTEPS = 5  # steps per period of identify's default integrator, for the recording and the fit alike
FIGURES = ("position.png", "residual_spectrum.png", "frf.png", "stiffness_ellipse.png")


def _config() -> dict:
    """The good config, as sections of plain values (the start 15-20% off the truth)."""
    return {
        "controller": {"type": "pd", "kp": [[250.0, 0.0], [0.0, 250.0]]},
        "acquisition": {"mode": "instant"},
        "sensors": {"force_noise": 0.05, "encoder_counts": 2**18},
        "voluntary": {"std": 0.1, "cutoff": 2.0},
        "arm": {
            **{k: (f * np.asarray(getattr(ARM, k))).tolist() for k, f in START.items()},
            "endpoint": np.asarray(ARM.endpoint).tolist(),
        },
        "friction": {"tau_c": 0.6, "tau_s": 1.2},
        "identify": {
            "free": ["arm.mass", "arm.damping", "arm.stiffness", "friction.tau_c"],
            "draws": 8,
            "jacobian_draws": 2,
            "substeps": SUBSTEPS,
        },
    }


@pytest.fixture(scope="module")
def recording_csv(tmp_path_factory):
    """A 3 s PD recording at location 2 (LuGre 0.8 / 1.2 N m, force noise 0.05 N, 2^18-count
    encoders, voluntary force 0.1 N RMS below 2 Hz, perturbation peak 10 N), as the six columns."""
    truth = aj.make_trial(
        aj.PD(),
        arm=ARM,
        friction=aj.LuGre(0.8, 1.2),
        sensors=aj.Sensors(force_noise=0.05, encoder_counts=2**18),
        voluntary=aj.VoluntaryForce(0.1, 2.0),
    )
    f = aj.perturbation(jax.random.key(0), N_SAMPLES, 10.0)
    sim = jax.jit(aj.simulate, static_argnames="numerics")(
        truth, f, key=jax.random.key(1), numerics=aj.Numerics(solver=aj.solvers.GradedARK4(), substeps=SUBSTEPS)
    )
    assert not bool(sim.diverged)
    path = tmp_path_factory.mktemp("recording") / "rec.csv"
    data = np.column_stack([f, sim.x, sim.fh])
    np.savetxt(path, data, delimiter=",", fmt="%.17g", header="f_delta_x,f_delta_y,x,y,fh_x,fh_y", comments="")
    return path


@pytest.fixture(scope="module")
def identified(recording_csv, tmp_path_factory):
    """One run of the script's model route: ``(exit code, stdout, output folder)``."""
    folder = tmp_path_factory.mktemp("identified")
    config = write_toml(folder / "config.toml", _config())
    out = folder / "out"
    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout):
        code = script.main([str(recording_csv), "--fs", "1000", "--model", str(config), "--out", str(out)])
    return code, stdout.getvalue(), out


def _strict(path):
    return json.loads(path.read_text(), parse_constant=lambda c: pytest.fail(f"not strict JSON: {c}"))


def _finite(value) -> bool:
    return bool(np.all(np.isfinite(np.asarray(value, dtype=float))))


def test_model_route_recovers_the_stiffness_and_writes_finite_results(identified, recording_csv):
    code, printed, out = identified
    assert code == 0, printed
    result = _strict(out / "identification.json")
    for key in ("settings", "record", "converged", "message", "cost", "iterations", "parameters", "labels"):
        assert key in result, key
    for key in ("covariance", "vaf", "whiteness_p", "classical", "start_model", "fitted_model", "warnings"):
        assert key in result, key
    settings = result["settings"]
    assert settings["recording"] == str(recording_csv) and settings["fs_hz"] == 1000.0
    assert settings["armimp_jax"] == aj.__version__
    assert settings["config"]["identify"]["free"] == _config()["identify"]["free"]
    assert settings["config"]["friction"]["sigma0"] is None  # the library's default, recorded as such
    assert result["record"] == {"n_samples": N_SAMPLES, "duration_s": N_SAMPLES / 1000.0}
    labels = result["labels"]
    assert len(labels) == 14 and labels[0] == "arm.mass[0,0]" and labels[-1] == "friction.tau_c[1]"
    cov = np.asarray(result["covariance"])
    assert cov.shape == (14, 14) and _finite(cov)
    np.testing.assert_allclose(cov, cov.T, rtol=1e-12, atol=1e-12 * np.abs(cov).max())
    assert np.all(np.diag(cov) > 0)
    # the matched statistics by label: the classical arm entries, then per joint the friction regression
    stats = result["statistics"]
    assert list(stats)[:2] == ["arm.mass[0,0]", "arm.mass[0,1]"] and _finite(list(stats.values()))
    assert len(stats) == 12 + 8
    for j in (0, 1):  # the regression's Coulomb coefficient measures the 0.8 N m of the recording
        assert 0.5 < stats[f"friction coulomb[{j}]"] / 0.8 < 1.5, stats
    for name, entry in result["parameters"].items():
        for field in ("value", "se"):
            assert _finite(entry[field]), (name, field)
        for index, e in entry["entries"].items():  # value +- z_0.975 se, z from the normal quantile
            assert math.isclose(e["high95"] - e["value"], 1.959963984540054 * e["se"], rel_tol=1e-9), (name, index)
            assert math.isclose(e["value"] - e["low95"], 1.959963984540054 * e["se"], rel_tol=1e-9), (name, index)
    assert set(result["parameters"]) == set(_config()["identify"]["free"])
    for field in ("cost", "iterations", "draws"):
        assert _finite(result[field])
    assert _finite(result["vaf"]["position"]) and _finite(result["vaf"]["force"])
    # the check of the intervals' linearity through friction needs draws beyond the chord's 8: at this
    # config's 8 it does not run, and nothing says it did (search.spread_ratio: test_identify.py)
    assert result["spread_ratio"] == {}
    assert not any("not linear" in w or "linearity" in w for w in result["warnings"])
    assert set(result["whiteness_p"]) == {"x", "y", "fh_x", "fh_y"} and _finite(list(result["whiteness_p"].values()))
    assert _finite(result["classical"]["stiffness"])
    assert result["fitted_model"]["controller_type"] == "PD"
    # the estimate of K: near the truth, and much nearer than the start (3 s, friction, noise)
    k = np.asarray(result["parameters"]["arm.stiffness"]["value"])
    assert np.abs(k - TRUE_K).max() <= 0.1 * np.abs(TRUE_K).max(), k
    assert np.linalg.norm(k - TRUE_K) < 0.5 * np.linalg.norm((START["stiffness"] - 1) * TRUE_K), k
    np.testing.assert_allclose(result["parameters"]["friction.tau_c"]["value"], 0.8, rtol=0.1)
    np.testing.assert_allclose(result["fitted_model"]["arm"]["stiffness"], k, rtol=1e-12)


def test_model_route_prints_a_summary_and_writes_the_table_and_figures(identified):
    code, printed, out = identified
    assert code == 0, printed
    result = _strict(out / "identification.json")
    lines = printed.splitlines()
    assert ("converged" in lines) == result["converged"]
    assert any(line.startswith("NOT CONVERGED: ") for line in lines) == (not result["converged"])
    k = result["parameters"]["arm.stiffness"]["entries"]["1,1"]
    assert f"  arm.stiffness[1,1] [N/m]: {k['value']:10.4g} +- {k['se']:.3g}" in printed
    assert "friction.tau_c[0] [N m]:" in printed and "VAF [%]: x " in printed and "Ljung-Box p" in printed
    warned = [line.removeprefix("WARNING: ") for line in lines if line.startswith("WARNING: ")]
    assert warned == result["warnings"]
    assert warned or "no warnings: the fit looks sound" in lines
    table = pd.read_csv(out / "identification.csv", dtype={"index": str})
    assert list(table.columns[:8]) == ["parameter", "index", "label", "unit", "value", "se", "low95", "high95"]
    assert len(table) == 14 and list(table["label"]) == result["labels"]
    row = table[table["label"] == "arm.stiffness[0,1]"].iloc[0]
    assert row["unit"] == "N/m" and row["index"] == "0,1"
    entry = result["parameters"]["arm.stiffness"]["entries"]["0,1"]
    for column in ("value", "se", "low95", "high95", "classical"):
        assert row[column] == pytest.approx(entry[column], rel=1e-12), column
    assert table[table["parameter"] == "friction.tau_c"]["classical"].isna().all()
    for name in FIGURES:
        assert (out / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", name
    assert not [p.name for p in out.iterdir() if p.name.startswith(".")]  # no temporary files left


def _run_bad(args, tmp_path, capsys) -> str:
    out = tmp_path / "out"
    code = script.main([*map(str, args), "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2, err
    assert not out.exists()  # refused before any work
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("estimate_recording: error: "), err
    return lines[0]


def _edit(**changes):
    """The good config with ``section=value`` changes (``None`` drops the section; a dict
    updates its keys, a key set to ``None`` is dropped)."""
    config = _config()
    for section, change in changes.items():
        if change is None:
            config.pop(section)
            continue
        table = {**config.get(section, {}), **change}
        config[section] = {k: v for k, v in table.items() if v is not None}
    return config


BAD_CONFIGS = {
    "unknown parameter": (
        _edit(identify={"free": ["arm.stiffness", "arm.inertia"]}),
        r"\[identify\] free: unknown parameter 'arm.inertia'; allowed: arm.mass, arm.damping, arm.stiffness, "
        r"friction.tau_c, friction.viscous, friction.tau_s",
    ),
    "unknown key": (
        _edit(sensors={"force_nosie": 0.05}),
        r"\[sensors\] unknown key 'force_nosie'; allowed: force_noise, encoder_counts, velocity_noise",
    ),
    "IMBIC key under PD": (
        _edit(controller={"mhat": [[0.3, 0.0], [0.0, 0.3]]}),
        r"\[controller\] unknown key 'mhat' for type 'pd'; allowed: type, kp, kv",
    ),
    "unknown section": (dict(_config(), sensor={"force_noise": 0.05}), r"unknown section \[sensor\]; allowed: robot,"),
    "missing section": (_edit(arm=None), r"missing section \[arm\]; required: controller, arm, friction, identify"),
    "missing key": (
        _edit(arm={"stiffness": None}),
        r"\[arm\] missing key 'stiffness' \[N/m\]; required: mass, damping, stiffness, endpoint",
    ),
    "wrong shape": (
        _edit(arm={"stiffness": [100.0, 200.0]}),
        r"\[arm\] stiffness \[N/m\] must be a 2x2 array \[\[a, b\], \[c, d\]\], got \[100.0, 200.0\]",
    ),
    "ragged matrix": (
        _edit(controller={"kv": [[4.0, 0.0], [0.0]]}),
        r"\[controller\] kv \[N s/m\] must be a 2x2 array",
    ),
    "text for a number": (_edit(friction={"tau_c": "0.3"}), r"\[friction\] tau_c \[N m\] must be a number or a list"),
    "unknown controller": (
        _edit(controller={"type": "pid"}),
        r"\[controller\] type: unknown controller type 'pid'; known: admittance, imbic, pd",
    ),
    "unknown acquisition": (
        _edit(acquisition={"mode": "delay"}),
        r"\[acquisition\] mode must be one of 'instant', 'interval_mean', got 'delay'",
    ),
    "draws too few": (_edit(identify={"draws": 5}), r"\[identify\] draws must be an integer >= 8"),
    "symmetric not free": (
        _edit(identify={"symmetric": ["arm.mass"], "free": ["arm.stiffness"]}),
        r"\[identify\] symmetric names 'arm.mass', which is not a free arm matrix; allowed: arm.stiffness",
    ),
    "stiction below Coulomb": (_edit(friction={"tau_s": 0.1}), r"\[friction\] LuGre: tau_s must be >= tau_c"),
    "mass not definite": (
        _edit(arm={"mass": [[1.0, 0.0], [0.0, -1.0]]}),
        r"\[arm\] Arm: mass .*positive semi-definite",
    ),
    "calibration's unknown key": (
        _edit(calibration={"robot_file": ["alone.csv"]}),
        r"\[calibration\] unknown key 'robot_file'; allowed: robot_files, robot_force, cutoff, min_rate, load_files",
    ),
    "calibration of nothing": (
        _edit(calibration={"cutoff": 40.0}),
        r"\[calibration\] calibrates nothing: give robot_files \(the robot alone\), load_files, or both",
    ),
    "calibration's cut-off not positive": (
        _edit(calibration={"robot_files": ["alone.csv"], "cutoff": -5.0}),
        r"\[calibration\] cutoff must be > 0 Hz, got -5",
    ),
    "a calibrated parameter free": (
        _edit(calibration={"robot_files": ["alone.csv"]}),
        r"\[identify\] free names friction.tau_c, which \[calibration\] calibrates: it is held",
    ),
}


@pytest.mark.parametrize("case", BAD_CONFIGS)
def test_bad_configs_get_one_line_naming_the_key(case, recording_csv, tmp_path, capsys):
    config, message = BAD_CONFIGS[case]
    path = write_toml(tmp_path / "config.toml", config)
    line = _run_bad([recording_csv, "--fs", "1000", "--model", path], tmp_path, capsys)
    assert re.search(message, line), line
    with pytest.raises(idr.IdentifyConfigError, match=message):
        idr.build_model(idr.read_identify_config(path), where=str(path))


def test_bad_files_and_rates_get_one_line(recording_csv, tmp_path, capsys):
    good = write_toml(tmp_path / "good.toml", _config())
    line = _run_bad([recording_csv, "--fs", "500", "--model", good], tmp_path, capsys)
    assert re.search(r"sample rate 500 Hz is not the simulator's control rate 1000 Hz", line), line
    line = _run_bad([recording_csv, "--fs", "1000", "--model", tmp_path / "nope.toml"], tmp_path, capsys)
    assert re.search(r"nope.toml: no such file", line), line
    (tmp_path / "broken.toml").write_text("[arm\nmass = 1\n")
    line = _run_bad([recording_csv, "--fs", "1000", "--model", tmp_path / "broken.toml"], tmp_path, capsys)
    assert re.search(r"broken.toml: not valid TOML", line), line
    line = _run_bad([tmp_path / "missing.csv", "--fs", "1000", "--model", good], tmp_path, capsys)
    assert re.search(r"cannot read .*missing.csv: it does not exist", line), line


def test_welch_options_are_refused_with_the_model_route(recording_csv, tmp_path, capsys):
    good = write_toml(tmp_path / "good.toml", _config())
    with pytest.raises(SystemExit) as exc:
        script.main([str(recording_csv), "--fs", "1000", "--model", str(good), "--out", "x", "--nperseg", "512"])
    assert exc.value.code == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert lines == [
        "estimate_recording: error: --model takes its settings from the config; not with the Welch route's --nperseg"
    ]


def test_every_kind_reads_from_a_config_and_the_docs_table_lists_its_keys(tmp_path):
    """A config names any of the package's controller and friction kinds with that kind's own keys
    (read from its class); docs/identify_recording.md's config table names every kind, each of
    its keys and every name [identify] free takes."""
    from armimp_jax._identification.layout import parameter_units
    from armimp_jax._model.controllers import CONTROLLER_KINDS
    from armimp_jax._model.friction import FRICTION_KINDS

    config = _config() | {
        "controller": {"type": "admittance", "m_v": [[3.0, 0.0], [0.0, 3.0]], "k_v": [[40.0, 0.0], [0.0, 60.0]]},
        "friction": {"type": "coulomb_viscous", "tau_c": 0.05, "viscous": [0.01, 0.02]},
        "identify": {"free": ["arm.stiffness", "friction.viscous"], "draws": 8},
    }
    model, options = idr.build_model(idr.read_identify_config(write_toml(tmp_path / "c.toml", config)))
    assert type(model.controller) is aj.Admittance and type(model.friction) is aj.CoulombViscous
    np.testing.assert_array_equal(model.controller.k_v, [[40.0, 0.0], [0.0, 60.0]])
    np.testing.assert_array_equal(model.friction.viscous, [0.01, 0.02])
    assert options["free"] == ("arm.stiffness", "friction.viscous")
    text = (ROOT / "docs" / "identify_recording.md").read_text()
    table = text[text.index("## The config (TOML)") : text.index("## Several recordings")]
    for registry in (CONTROLLER_KINDS, FRICTION_KINDS):
        for cls in (registry.get(n) for n in registry.names()):
            if cls.__module__.startswith("armimp_jax."):  # not a test's own kind
                assert f'"{cls.kind}"' in table, cls.kind
                assert all(f"`{name}`" in table for name in cls.parameters()), cls.kind
    assert all(f"`{name}`" in table for name in parameter_units())


def test_example_config_builds_the_documented_model():
    config = idr.read_identify_config(EXAMPLE)
    model, options = idr.build_model(config, where=str(EXAMPLE))
    assert type(model.controller).__name__ == "PD" and model.acquisition == "instant"
    assert model.voluntary is not None and model.sensors.force_on and model.sensors.encoder_on
    np.testing.assert_allclose(model.x0, np.asarray(config["arm"]["endpoint"]), atol=1e-9)
    assert options["free"] == ("arm.mass", "arm.damping", "arm.stiffness", "friction.tau_c")
    numerics = options["numerics"]
    assert (numerics.method, numerics.substeps) == ("gark4", 4) and options["draws"] == 64
    assert "sweeps/configs/identify_example.toml" in (ROOT / "docs" / "identify_recording.md").read_text()


def test_stiffness_ellipse_radius_and_draws_from_the_covariance():
    phi = np.array([0.0, np.pi / 2, np.pi / 4])
    np.testing.assert_allclose(recording_figures.ellipse_radius(np.diag([100.0, 400.0]), phi)[:2], [100.0, 400.0])
    # the ellipse's extremes are the eigenvalues of the symmetric part, whatever the rotation
    k = np.array([[200.0, -80.0], [-20.0, 300.0]])
    grid = np.linspace(0.0, np.pi, 20001)
    r = recording_figures.ellipse_radius(k, grid)
    np.testing.assert_allclose([r.min(), r.max()], np.linalg.eigvalsh(0.5 * (k + k.T)), rtol=1e-6)
    assert recording_figures.ellipse_radius(np.stack([k, 2 * k]), phi).shape == (2, 3)
    # draws of K from the covariance of its entries (others in the covariance ignored)
    labels = ["arm.mass[0,0]"] + [f"arm.stiffness[{i},{j}]" for i in range(2) for j in range(2)]
    cov = np.diag([1.0, 4.0, 1.0, 1.0, 9.0])
    cov[1, 4] = cov[4, 1] = 3.0
    res = types.SimpleNamespace(labels=labels, covariance=cov, values={"arm.stiffness": k})
    draws = recording_figures.stiffness_draws(res, n=20000)
    assert draws.shape == (20000, 2, 2)
    np.testing.assert_allclose(draws.mean(axis=0), k, atol=0.1)
    np.testing.assert_allclose(np.cov(draws.reshape(-1, 4).T), cov[1:, 1:], atol=0.25)
    assert recording_figures.stiffness_draws(types.SimpleNamespace(labels=labels[:1])) is None


def test_classical_column_is_the_welch_routes_default_fit(identified, recording_csv):
    """The classical answer beside the arm's is what the Welch route prints by default for the
    same recording: segments that follow the record, a fitted delay, spectral SEs."""
    code, printed, out = identified
    assert code == 0, printed
    result = _strict(out / "identification.json")
    rec = recording.load_recording(recording_csv)
    _, fit = estimate_recording.analyse(rec, fs=1000.0)
    classical = result["classical"]
    assert classical["settings"]["acquisition"] == "delay" and classical["settings"]["se"] == "spectral"
    assert classical["settings"]["nperseg"] == aj.spectra.welch_segments(N_SAMPLES)[0]
    for name in ("mass", "damping", "stiffness", "damping_se", "delay"):
        np.testing.assert_allclose(classical[name], getattr(fit, name), rtol=1e-9, err_msg=name)
    entry = result["parameters"]["arm.damping"]["entries"]["1,1"]
    assert entry["classical"] == pytest.approx(float(fit.damping[1, 1]), rel=1e-9)
    assert entry["classical_se"] == pytest.approx(float(fit.damping_se[1, 1]), rel=1e-9)
    assert f"(classical {float(fit.damping[1, 1]):.4g})" in printed


def test_a_sensitivity_the_model_cannot_give_is_refused_before_the_fit(recording_csv, tmp_path, capsys):
    """--sensitivity wants a percentage, the model route, a free arm and the config's noise; each
    refusal is one line, before any identification (no output folder)."""
    good = write_toml(tmp_path / "good.toml", _config())
    args = [str(recording_csv), "--fs", "1000", "--model", str(good), "--out", "x"]
    for value in ("0", "150"):
        with pytest.raises(SystemExit) as exc:
            script.main([*args, "--sensitivity", value])
        assert exc.value.code == 2
        assert "--sensitivity takes a percentage in (0, 100] with --model" in capsys.readouterr().err
    quiet = {k: v for k, v in _config().items() if k not in ("sensors", "voluntary")}
    no_arm = dict(_config(), identify=dict(_config()["identify"], free=["friction.tau_c"]))
    for name, config, message in (
        ("quiet", quiet, r"--sensitivity needs the config's noise"),
        ("no_arm", no_arm, r"--sensitivity needs the arm free"),
    ):
        path = write_toml(tmp_path / f"{name}.toml", config)
        line = _run_bad([recording_csv, "--fs", "1000", "--model", path, "--sensitivity", "10"], tmp_path, capsys)
        assert re.search(message, line), line


@pytest.mark.slow  # about 40 s cold: an identification and a robot_sensitivity
def test_the_sensitivity_table_prints_robot_sensitivitys_numbers_for_what_was_not_estimated(recording_csv, tmp_path):
    """--sensitivity 10 prints aj.experiment.robot_sensitivity at the identified trial (the robot's
    parameters that were not free: tau_c was estimated, so it has no column), to its 2 decimals."""
    config = write_toml(tmp_path / "config.toml", _config())
    stdout = io.StringIO()
    args = [str(recording_csv), "--fs", "1000", "--model", str(config), "--out", str(tmp_path / "out")]
    with contextlib.redirect_stdout(stdout):
        assert script.main([*args, "--sensitivity", "10"]) == 0
    text = stdout.getvalue()
    head = next(line for line in text.splitlines() if line.startswith("| arm entry |"))
    assert "friction.tau_c" not in head and "robot.inertia[0]" in head
    doc = json.loads((tmp_path / "out" / "identification.json").read_text())
    trial = idr.build_model(idr.read_identify_config(config), where="config")[0]
    values = {n: np.asarray(v["value"]) for n, v in doc["parameters"].items()}
    fitted = aj.Arm(values["arm.mass"], values["arm.damping"], values["arm.stiffness"], ARM.endpoint)
    trial = dataclasses.replace(trial, arm=fitted, friction=aj.LuGre(values["friction.tau_c"], 1.2))
    rec = recording.load_recording(recording_csv)
    robot = [n for n in head.strip("| ").split(" | ")[1:]]
    options = dict(_config()["identify"])
    sens = aj.experiment.robot_sensitivity(
        trial,
        rec["f_delta"],
        robot=tuple(dict.fromkeys(n.split("[")[0].removesuffix(" (per ms)") for n in robot)),
        plausible=10.0,
        draws=options["draws"],
        jacobian_draws=options["jacobian_draws"],
        numerics=aj.Numerics(solver=aj.solvers.GradedARK4(), substeps=SUBSTEPS),
    )
    assert sens.table() in text


@pytest.fixture(scope="module")
def calibration_files(tmp_path_factory):
    """The recording's robot alone (no_arm at its rest, the same LuGre and noise), two 3 s PD records
    of 10 N peak as command_x, command_y, x, y, fh_x, fh_y; five known loads read 20 times each through
    a gain of 1.03 and 0.97 and an offset of 0.2 and -0.1 N (load_x, load_y, fh_x, fh_y)."""
    folder = tmp_path_factory.mktemp("calibration")
    alone = aj.make_trial(
        aj.PD(),
        arm=aj.presets.no_arm(ARM.endpoint),
        friction=aj.LuGre(0.8, 1.2),
        sensors=aj.Sensors(force_noise=0.05, encoder_counts=2**18),
    )
    run = jax.jit(aj.simulate, static_argnames="numerics")
    numerics = aj.Numerics(solver=aj.solvers.GradedARK4(), substeps=SUBSTEPS)
    head = "command_x,command_y,x,y,fh_x,fh_y"
    for i in range(2):
        f = aj.perturbation(jax.random.key(20 + i), N_SAMPLES, 10.0)
        sim = run(alone, f, key=jax.random.key(30 + i), numerics=numerics)
        assert not bool(sim.diverged)
        data = np.column_stack([sim.fu, sim.x, sim.fh])
        np.savetxt(folder / f"alone{i}.csv", data, delimiter=",", fmt="%.17g", header=head, comments="")
    loads = np.repeat(9.81 * np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [0.0, 1.0], [0.0, 2.0]]), 20, axis=0)
    noise = 0.05 * np.random.default_rng(7).standard_normal(loads.shape)
    readings = np.array([1.03, 0.97]) * loads + np.array([0.2, -0.1]) + noise
    header = "load_x,load_y,fh_x,fh_y"
    np.savetxt(folder / "loads.csv", np.column_stack([loads, readings]), delimiter=",", header=header, comments="")
    return folder


def _calibrated_config(folder, **calibration) -> pathlib.Path:
    config = _edit(identify={"free": ["arm.mass", "arm.damping", "arm.stiffness", "sensors.force_offset"]})
    config["friction"] = {"tau_c": 0.8, "tau_s": 1.2}
    config["calibration"] = {"robot_files": ["alone0.csv", "alone1.csv"], "load_files": ["loads.csv"], **calibration}
    return write_toml(folder / "calibrated.toml", config)


def test_the_calibration_section_calibrates_the_robot_and_the_transducer_from_files(calibration_files):
    """``[calibration]``'s files (relative to the config) give ``calibrate_robot``'s and
    ``calibrate_force``'s answers on the same arrays, and their tables in that order."""
    from armimp_jax.study.recording import calibration_files as cf

    path = _calibrated_config(calibration_files)
    config = idr.read_identify_config(path)
    model, _ = idr.build_model(config)
    cals, lines = cf.calibrate(config, path, 1000.0, {}, model.robot)
    robot, force = cals
    data = [np.loadtxt(calibration_files / f"alone{i}.csv", delimiter=",", skiprows=1) for i in range(2)]
    direct = aj.calibrate_robot([aj.RobotRecording(x=d[:, 2:4], command=d[:, :2], fh=d[:, 4:]) for d in data])
    np.testing.assert_array_equal(robot.covariance, direct.covariance)
    gain, se = force.values["sensors.force_gain"], force.se["sensors.force_gain"]
    assert np.all(np.abs(gain - [1.03, 0.97]) <= 5 * se), (gain, se)
    text = "\n".join(lines)
    assert text.index("| robot.inertia[0] (c1) |") < text.index("| sensors.force_gain[0] |")
    json.dumps(cf.record(cals), default=lambda a: np.asarray(a).tolist())  # every number serialisable


def test_bad_calibration_files_get_one_line_before_the_fit(calibration_files, recording_csv, tmp_path, capsys):
    """A missing file, a robot that does not move, loads all equal and a cut-off above the Nyquist
    rate: one line each, exit status 2, nothing written."""
    still = np.loadtxt(calibration_files / "alone0.csv", delimiter=",", skiprows=1)
    still[:, 2:4] = still[0, 2:4]
    head = "command_x,command_y,x,y,fh_x,fh_y"
    np.savetxt(calibration_files / "still.csv", still, delimiter=",", fmt="%.17g", header=head, comments="")
    loads = np.loadtxt(calibration_files / "loads.csv", delimiter=",", skiprows=1)
    loads[:, 0] = 9.81
    header = "load_x,load_y,fh_x,fh_y"
    np.savetxt(calibration_files / "equal.csv", loads, delimiter=",", header=header, comments="")
    cases = (
        (dict(robot_files=["nope.csv"]), r"cannot read .*nope.csv: it does not exist"),
        (dict(robot_files=["still.csv"]), r"recording 1: the robot does not move: joint 1 never turns"),
        (dict(load_files=["equal.csv"]), r"calibrate_force: the loads along x are all equal"),
        (dict(cutoff=600.0), r"cutoff must be in \(0, 500\) Hz, below its samples' Nyquist rate"),
    )
    for change, message in cases:
        path = _calibrated_config(calibration_files, **change)
        line = _run_bad([recording_csv, "--fs", "1000", "--model", path], tmp_path, capsys)
        assert re.search(message, line), line


@pytest.mark.slow  # 875 s on two cores shared with three other runs: an identification through the calibration
def test_the_model_route_prints_the_calibration_before_the_arm_and_carries_it(
    calibration_files, recording_csv, tmp_path
):
    """The script prints the calibrations' tables before the arm's, and identification.json holds them."""
    path = _calibrated_config(calibration_files)
    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout):
        code = script.main([str(recording_csv), "--fs", "1000", "--model", str(path), "--out", str(tmp_path / "o")])
    text = stdout.getvalue()
    assert code == 0, text
    assert text.index("| robot.inertia[0] (c1) |") < text.index("identifying") < text.index("arm.stiffness")
    doc = _strict(tmp_path / "o" / "identification.json")
    kinds = [c["kind"] for c in doc["settings"]["calibration"]]
    assert kinds == ["RobotCalibration", "ForceCalibration"]
    assert _finite(doc["parameters"]["arm.stiffness"]["se"])
