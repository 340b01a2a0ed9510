"""The general sweep (armimp_jax/study/sweep/sweep.py, sweeps/sweep.py) on a tiny grid, end to end."""

from __future__ import annotations

import csv
import importlib.util
import json
import math
import pathlib
import subprocess
import sys

import numpy as np
import pytest
from scipy import stats

from armimp_jax.study.schema import grids
from armimp_jax.study.schema import points as sp
from armimp_jax.study.sweep import stats as study_stats
from armimp_jax.study.sweep import sweep

ROOT = pathlib.Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "sweeps" / "sweep.py"
# 2 s records, 512-sample segments, 5 ARK3 substeps: 6 points (PD ignores mhat) x 2 seeds.
# IMBIC with mhat = 40 kg (far above 2 M_x) diverges: those trials must be counted and left out.
CLI = [
    "--set", "controller=pd,imbic",
    "--set", "mhat=0.25,40",
    "--set", "friction.tau_c=0,0.5",
    "--seconds", "2", "--nperseg", "512", "--seeds", "2", "--substeps", "5",
]  # fmt: skip
TOML = """
[controller]
type = ["pd", "imbic"]
mhat = [0.25, 40]

[friction]
tau_c = [0.0, 0.5]

[record]
seconds = 2

[welch]
nperseg = 512

[run]
seeds = 2
substeps = 5
"""


def strict_load(path):
    def refuse(token):
        raise AssertionError(f"{path}: non-standard JSON constant {token}")

    return json.loads(pathlib.Path(path).read_text(), parse_constant=refuse)


def read_csv(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


@pytest.fixture(scope="module")
def script():
    spec = importlib.util.spec_from_file_location("sweep_script", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture
def main(script, monkeypatch):
    """The script's main(argv) in this process (float64 is on already; the CPU split is not redone)."""
    import armimp_jax.runtime

    monkeypatch.setattr(armimp_jax.runtime, "configure", lambda **_: 1)
    return script.main


def one_line_error(capsys, call, *fragments):
    with pytest.raises(SystemExit) as exc:
        call()
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("sweep: error: "), err
    for f in fragments:
        assert f in err[0], err[0]
    return err[0]


@pytest.fixture(scope="module")
def tiny(tmp_path_factory, script):
    import armimp_jax.runtime

    out = tmp_path_factory.mktemp("sweep") / "run"
    saved = armimp_jax.runtime.configure
    armimp_jax.runtime.configure = lambda **_: 1
    try:
        assert script.main([*CLI, "--out", str(out)]) == 0
    finally:
        armimp_jax.runtime.configure = saved
    return out


def test_tiny_sweep_writes_a_row_per_trial_and_a_summary_per_point(tiny):
    rows = read_csv(tiny / "trials.csv")
    assert len(rows) == 12  # 2 PD points + 4 IMBIC points, 2 seeds each
    for col in ("controller", "tau_c", "tau_s", "arm", "peak_x", "seconds", "mhat", "nperseg", "seed", "method",
                "substeps", "phi_T", "phi_12", "coh_min", "coh_fh2_median", "M_11", "B_22_se", "K_21", "vaf_overall",
                "diverged"):  # fmt: skip
        assert col in rows[0], col
    assert {r["method"] for r in rows} == {"ark3"} and {r["substeps"] for r in rows} == {"5"}
    assert {r["mhat"] for r in rows if r["controller"] == "pd"} == {""}  # PD has no mhat
    sound = [r for r in rows if r["diverged"] == "False"]
    import armimp_jax as aj
    from armimp_jax import presets

    for r in sound:  # each row holds its trial's numbers: phi_T and coh_min of its saved estimate, recomputed
        saved = np.load(tiny / "trials" / f"{r['trial_id']}.npz")
        phi = float(aj.spectra.accuracy(saved["Z"], saved["f"], presets.arm(int(r["arm"])))[0])
        assert float(r["phi_T"]) == pytest.approx(phi, rel=1e-12), r["trial_id"]
        lowest = min(saved["coh_multiple_x"].min(), saved["coh_multiple_fh"].min())
        assert float(r["coh_min"]) == pytest.approx(float(lowest), rel=1e-12), r["trial_id"]
    # the fit recovers the arm's mass to 15% (2 s records: measured -4% to -11% under PD)
    m11 = float(np.asarray(presets.arm(1).mass)[0, 0])
    assert all(abs(float(r["M_11"]) / m11 - 1) < 0.15 for r in sound if r["controller"] == "pd")
    summary = read_csv(tiny / "summary.csv")
    assert len(summary) == 6 and {"phi_T_mean", "phi_T_sd", "phi_T_ci_lo", "phi_T_ci_hi", "n", "diverged"} <= set(
        summary[0]
    )
    assert (tiny / "tau_c.png").stat().st_size > 1000
    assert len(list((tiny / "trials").glob("*.npz"))) == 12


def test_summary_statistics_match_a_hand_computation(tiny):
    rows = [r for r in read_csv(tiny / "trials.csv") if r["controller"] == "pd" and float(r["tau_c"]) == 0.5]
    phi = np.array([float(r["phi_T"]) for r in rows])
    assert len(phi) == 2
    mean, sd = phi.mean(), phi.std(ddof=1)
    half = stats.t.ppf(0.975, 1) * sd / math.sqrt(2)
    result = strict_load(tiny / "summary.json")
    (cond,) = [c for c in result["conditions"] if c["point"]["controller"] == "pd" and c["point"]["tau_c"] == 0.5]
    st = cond["stats"]["phi_T"]
    assert cond["n"] == 2 and cond["diverged"] == 0
    np.testing.assert_allclose([st["mean"], st["sd"], st["ci_lo"], st["ci_hi"]], [mean, sd, mean - half, mean + half])


def test_outputs_are_strict_json_with_keys(tiny):
    run = strict_load(tiny / "run.json")
    result = strict_load(tiny / "summary.json")
    assert run["key"] == result["key"] and run["settings"]["armimp_jax"]
    assert result["complete"] and result["trials"] == result["trials_expected"] == 12
    assert "NaN" not in (tiny / "summary.json").read_text()
    assert result["swept"] == ["controller", "tau_c", "mhat"]


def test_the_dataframes_are_the_csv_files_read_back(tiny):
    """load_sweep / load_summary build the tables from the checked records; the CSV files
    (and the Parquet ones, with pyarrow) hold the same table, every number exactly."""
    import pandas as pd

    from armimp_jax.study import load_summary, load_sweep
    from armimp_jax.study.sweep import tables

    trials = load_sweep(tiny)
    assert len(trials) == 12 and list(trials.columns) == tables.trial_columns(sweep.saved_settings(tiny).points)
    assert trials["phi_T"].dtype == "float64" and trials["diverged"].dtype == bool and trials["arm"].iloc[0] == "1"
    assert trials.loc[trials["controller"] == "pd", "mhat"].isna().all()  # PD has no mhat
    pd.testing.assert_frame_equal(tables.read_table(tiny / "trials.csv", tables.TRIAL_DTYPES), trials, check_exact=True)
    summary = load_summary(tiny)
    pd.testing.assert_frame_equal(
        tables.read_table(tiny / "summary.csv", tables.SUMMARY_DTYPES), summary, check_exact=True
    )
    assert tables.has_parquet()  # pyarrow comes with .[test]
    pd.testing.assert_frame_equal(pd.read_parquet(tiny / "trials.parquet"), trials, check_exact=True)
    # the summary is the seed statistics of the trial table
    sound = trials[~trials["diverged"]].groupby("point_index")["phi_T"]
    np.testing.assert_allclose(summary.loc[summary["n"] > 0, "phi_T_mean"], sound.mean(), rtol=1e-14)
    np.testing.assert_allclose(summary.loc[summary["n"] > 0, "phi_T_sd"], sound.std(ddof=1), rtol=1e-12)


def test_diverged_trials_are_counted_and_left_out_of_every_statistic(tiny):
    result = strict_load(tiny / "summary.json")
    wild = [c for c in result["conditions"] if c["point"].get("mhat") == 40]
    assert len(wild) == 2
    for c in wild:
        assert c["diverged"] == 2 and c["n"] == 0 and c["diverged_seeds"] == [0, 1]
        assert c["stats"]["phi_T"]["mean"] is None  # NaN written as null
    assert len(result["diverged"]) == 4
    rows = read_csv(tiny / "trials.csv")
    assert sum(r["diverged"] == "True" for r in rows) == 4
    summary = read_csv(tiny / "summary.csv")
    assert [r["phi_T_mean"] for r in summary if r["mhat"] and float(r["mhat"]) == 40] == ["", ""]


def test_rerun_reuses_every_trial_and_toml_equals_the_command_line(tiny, main, tmp_path, capsys):
    before = {p.name: p.stat().st_mtime_ns for p in (tiny / "trials").glob("*.npz")}
    assert main([*CLI, "--out", str(tiny)]) == 0
    assert "0 trials on disk" not in capsys.readouterr().out
    config = tmp_path / "grid.toml"
    config.write_text(TOML)
    assert main(["--config", str(config), "--out", str(tiny)]) == 0  # the same run: nothing computed
    assert "12 trials on disk, 0 to run" in capsys.readouterr().out
    assert {p.name: p.stat().st_mtime_ns for p in (tiny / "trials").glob("*.npz")} == before
    grid, points, run = grids.read_toml(config)
    from_toml = sweep.SweepSettings(tuple(grids.expand(grid, points)), **run)
    from_cli = sweep.saved_settings(tiny)
    assert from_toml == from_cli


def test_other_settings_are_refused_in_one_line(tiny, main, capsys):
    line = one_line_error(capsys, lambda: main([*CLI[:-2], "--substeps", "6", "--out", str(tiny)]))
    assert "numerics.substeps=5 (you asked 6)" in line
    line = one_line_error(capsys, lambda: main([*CLI[:5], "tau_c=0,0.4", *CLI[6:], "--out", str(tiny)]))
    assert "tau_c=0.5 (you asked 0.4)" in line
    one_line_error(
        capsys, lambda: main(["--resume", str(tiny), "--seconds", "3"]), "--resume", "seconds=2 (you asked 3)"
    )


def test_a_damaged_record_is_named_and_recomputed(tiny, tmp_path, capsys):
    import shutil

    out = tmp_path / "copy"
    shutil.copytree(tiny, out)
    victim = sorted((out / "trials").glob("*.npz"))[0]
    victim.write_bytes(victim.read_bytes()[:200])
    warnings = []
    result = sweep.run_sweep(sweep.saved_settings(out), out, warn=warnings.append)
    assert result["computed"] == [victim.stem]
    assert len(warnings) == 1 and str(victim) in warnings[0] and "truncated" in warnings[0]
    # the same numbers up to round-off (a batch of one vectorises differently from a batch of four)
    new, old = strict_load(out / "summary.json")["conditions"], strict_load(tiny / "summary.json")["conditions"]
    assert [c["n"] for c in new] == [c["n"] for c in old]
    mean = [[c["stats"][m]["mean"] for m in ("phi_T", "coh_min", "K_11")] for c in new if c["n"]]
    np.testing.assert_allclose(
        mean, [[c["stats"][m]["mean"] for m in ("phi_T", "coh_min", "K_11")] for c in old if c["n"]], rtol=1e-9
    )


def test_a_folder_in_use_is_refused_at_once(tmp_path, main, capsys):
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys, time; from armimp_jax.study.runs.runfolder import RunLock\n"
         f"with RunLock({str(tmp_path)!r}):\n    print('held', flush=True); time.sleep(60)"],
        stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert holder.stdout.readline().strip() == "held"
        one_line_error(capsys, lambda: main([*CLI, "--out", str(tmp_path)]), "is in use by another run", "pid")
    finally:
        holder.kill()
        holder.wait()
        holder.stdout.close()


@pytest.mark.parametrize(
    "argv, fragment",
    [
        (["--set", "frictio=1", "--out", "X"], "unknown setting(s) 'frictio'"),
        (["--set", "friction=dahl", "--out", "X"], "unknown friction type 'dahl'; known: coulomb_viscous, lugre"),
        (["--set", "controller=mpc", "--out", "X"], "unknown controller type 'mpc'; known: admittance, imbic, pd"),
        (["--set", "tau_c=-1", "--out", "X"], "LuGre: tau_c must be >= 0 N m"),
        (["--set", "tau_c", "--out", "X"], "--set needs NAME=V1,V2"),
        (["--set", "arm=7", "--out", "X"], "arm must be a paper location"),
        (["--seconds", "0.5", "--out", "X"], "shorter than one Welch segment"),
        (["--set", "seconds=2", "--seconds", "3", "--out", "X"], "both given"),
        (["--seeds", "0", "--out", "X"], "--seeds must be >= 1"),
        (["--out", "X", "--resume", "Y"], "give one of --out DIR and --resume DIR"),
        (["--bogus"], "unrecognized arguments"),
    ],
)
def test_bad_options_fail_in_one_line(main, capsys, tmp_path, argv, fragment):
    argv = [str(tmp_path / a) if a == "X" else a for a in argv]
    one_line_error(capsys, lambda: main(argv), fragment)
    assert not (tmp_path / "X").exists()


@pytest.mark.parametrize(
    "text, fragment",
    [
        ("[friction\ntau_c = 1", "not valid TOML"),
        ("[frictions]\ntau_c = [1]", "unknown section [frictions]; allowed: arm, perturbation"),
        ("[friction]\ntau_c = [0]\n[run]\nseed = 3", "unknown [run] option(s) seed"),
        ("[friction]\ntau_c = [0]\n[[points]]\nfriction.tau_c = 1", "given both in a point and for every point"),
        ("[[points]]\narm = {mass = [[1, 0], [0, 1]]}", "a user arm needs exactly the keys"),
        ("[arm]\nlocation = 1\nmass = [[1, 0], [0, 1]]", "[arm] takes a location or a user's mass"),
        ("[friction]\nnperseg = 512", "unknown key 'nperseg' in [friction]; allowed: type, tau_c"),
        ("tau_c = 0.5", "tau_c = 0.5 sits outside a section; write it as [friction] tau_c"),
        ("arm = 2", "arm = 2 sits outside a section; write it as [arm] location"),
        ("[[points]]\narm = 2", "points[0]: arm = 2 sits outside a section; write it as arm.location = ..."),
        (
            "[[points]]\nrun.seeds = 3",
            "unknown section [run]; allowed: arm, perturbation, record, sensors, "
            "acquisition, welch, controller, friction",
        ),
        ("[[points]]\nrecord.seconds = [1, 2]", "a point's values are not swept: seconds in a point is a list"),
        ('[controller]\ntype = "nope"', "bad.toml: controller: unknown controller type 'nope'"),
        ('[friction]\ntype = ["lugre", "coulomb_viscous"]', "friction 'coulomb_viscous' needs tau_c: it has no"),
        # a kind's setting the run's kinds do not take is refused, not dropped in silence
        (
            '[controller]\ntype = "pd"\nmhat = 3',
            "mhat: not a setting of the kinds this run names (controller pd; friction lugre)",
        ),
        (
            "[grid]\narm = { mass = 1 }\nbogus = 2",
            "arm under [arm] location (or a user's mass, damping, stiffness, endpoint); bogus (no such setting)",
        ),
        # the old flat dialect: one line naming each setting's section
        (
            "[grid]\ntau_c = [0]\nseconds = 2",
            "[grid] is the old sweep dialect: name each setting in its section, "
            "as the trial configs do; tau_c under [friction] tau_c; seconds under [record] seconds",
        ),
    ],
)
def test_bad_toml_fails_in_one_line(main, capsys, tmp_path, text, fragment):
    config = tmp_path / "bad.toml"
    config.write_text(text)
    one_line_error(capsys, lambda: main(["--config", str(config), "--out", str(tmp_path / "o")]), str(fragment))


def test_a_point_s_per_joint_friction_reaches_its_columns(tmp_path):
    config = tmp_path / "pairs.toml"
    config.write_text('[controller]\ntype = ["pd", "imbic"]\nmhat = 0.5\n[[points]]\nfriction.tau_c = [0.1, 0.2]\n')
    grid, points, _ = grids.read_toml(config)
    pts = grids.expand(grid, points)
    assert [p["controller"] for p in pts] == ["pd", "imbic"] and pts[1]["mhat"] == 0.5 and "mhat" not in pts[0]
    assert json.loads(pts[0].columns["tau_s"]) == pytest.approx([0.15, 0.3])  # per joint, as tau_c


def test_a_point_is_typed_from_parse_to_table_its_parts_built_once():
    import jax

    import armimp_jax as aj

    point = sp.Point.parse(
        dict(controller="imbic", mhat=0.5, tau_c=0.3, arm=2, seconds=4.0, nperseg=1024, force_noise=0.05)
    )
    assert point == sp.normalize_point(point) and sp.Point.parse(point) is point  # its settings, parsed once
    assert point.trial is point.trial and isinstance(point.friction, aj.LuGre)  # built once, on first use
    assert point.samples == 4000 and point.noisy and point.group[:2] == ("imbic", "lugre")
    assert sweep.trial_id(dict(point), 3) == f"p{point.key}-s3"
    assert point.columns["tau_s"] == pytest.approx(0.3 * point["stiction_ratio"])
    # the same Trial as built by hand from the paper's parts
    by_hand = aj.make_trial(
        aj.IMBIC(mhat=0.5 * np.eye(2)),
        arm=aj.presets.arm(2),
        friction=aj.LuGre(0.3, 0.3 * point["stiction_ratio"]),
        sensors=aj.Sensors(force_noise=0.05),
    )
    for a, b in zip(jax.tree.leaves(point.trial), jax.tree.leaves(by_hand), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_points_normalise_and_deduplicate():
    user = dict(mass=[[1.5, 0], [0, 1]], damping=[[5, 0], [0, 5]], stiffness=[[100, 0], [0, 100]], endpoint=[0, 0.4])
    pts = grids.expand(
        dict(controller=["pd", "imbic"], mhat=[0.25, 0.5], arm=[1, user]), points=[dict(peak=3.0), dict(tau_c=1)]
    )
    # PD ignores mhat: 2 (peak/tau) x (PD 2 arms + IMBIC 2 mhat x 2 arms)
    assert len(pts) == 2 * (2 + 4)
    assert pts[0]["peak"] == [3.0, 3.0] and pts[0]["perturbation_level"] is None and "mhat" not in pts[0]
    assert pts[-1]["peak"] == [2.25, 2.25] and pts[-1]["noverlap"] == 6144
    assert sp.normalize_point(pts[3]) == pts[3]  # idempotent
    assert sp.point_columns(pts[1])["arm"].startswith("user-")
    assert grids.parse_set(["tau_c=geom:0.001:4:3", "peak=[1,2],3", 'window=hann,["tukey",0.5]']) == dict(
        tau_c=pytest.approx([1e-3, 0.063245553, 4.0]), peak=[[1, 2], 3], window=["hann", ["tukey", 0.5]]
    )
    trial = sp.Point.parse(dict(tau_c=2.0, arm=user, controller="imbic", mhat=0.5)).trial
    np.testing.assert_allclose(trial.friction.tau_s, [3.0, 3.0])
    np.testing.assert_allclose(trial.controller.mhat, 0.5 * np.eye(2))


def test_first_crossing_interpolates_in_log_tau():
    x = [0.0, 0.01, 0.1, 1.0]
    assert study_stats.first_crossing(x, [1.0, 1.0, 1.5, 3.0], 2.0) == pytest.approx(10 ** (-1 + 1 / 3))
    assert study_stats.first_crossing(x, [1.0, 3.0, 4.0, 5.0], 2.0) == pytest.approx(0.005)  # linear from 0
    assert math.isnan(study_stats.first_crossing(x, [1.0, 1.1, 1.2, 1.3], 2.0))
    assert study_stats.first_crossing(x, [0.99, 0.95, 0.8, 0.5], 0.9, above=False) == pytest.approx(10 ** (-2 + 1 / 3))
    boot = study_stats.bootstrap_crossing(x, np.array([[1.0, 1.0, 1.5, 3.0], [1.0, 1.2, 2.5, 3.0]]), lambda m: 2 * m[0])
    assert boot["seeds"] == 2 and boot["ci_lo"] <= boot["value"] <= boot["ci_hi"]
