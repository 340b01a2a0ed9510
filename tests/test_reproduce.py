"""The reproduction script end to end (quick mode), replot, resume, results that match their
settings (refusals, lock, corrupt records, strict JSON, diverged trials), and the claims
rules with their seed statistics."""

import dataclasses
import fcntl
import importlib.util
import json
import pathlib
import re
import shutil
import subprocess
import sys

import numpy as np
import pytest

from armimp_jax.paper import plots, report
from armimp_jax.paper import reproduce as repro
from armimp_jax.paper import tables as ptables
from armimp_jax.paper.claims import (
    Condition,
    condition_summary,
    evaluate_claims,
    fit_metrics,
    mean_ci,
    seed_summaries,
    trial_id,
    true_matrices,
)
from armimp_jax.presets._paper import arm
from armimp_jax.study.runs import engine
from armimp_jax.study.runs import results as res
from armimp_jax.study.runs.runfolder import StudyRun

ROOT = pathlib.Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "sweeps" / "reproduce_paper.py"
FIGURES = [
    "fig2_pd_bode.png",
    "fig3_pd_coherence.png",
    "fig4_pd_phi.png",
    "fig7_imbic_bode.png",
    "fig8_imbic_coherence.png",
    "fig9_imbic_phi.png",
    "ablation_acquisition.png",
]
TINY = repro.ReproSettings(seconds=2.2, substeps=4, nperseg=512, noverlap=384, seeds=1, ablation=False)
TINY_ARGS = ["--seconds", "2.2", "--substeps", "4", "--nperseg", "512", "--noverlap", "384", "--no-ablation"]


def run_script(*args):
    return subprocess.run([sys.executable, str(SCRIPT), *args], capture_output=True, text=True, cwd=ROOT, timeout=900)


def strict_loads(text):
    def refuse(token):
        raise AssertionError(f"results hold the non-JSON constant {token}")

    return json.loads(text, parse_constant=refuse)


def one_line_error(proc, *fragments):
    """The script refused with exit status 2 and one line naming ``fragments``, no traceback."""
    assert proc.returncode == 2, proc.stdout + proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("reproduce_paper: error: "), proc.stderr
    for f in fragments:
        assert f in lines[0], (f, lines[0])
    return lines[0]


@pytest.fixture(scope="module")
def script():
    """sweeps/reproduce_paper.py as a module (its top level imports the standard library only)."""
    spec = importlib.util.spec_from_file_location("reproduce_paper", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory, request):
    """A ``--quick`` run, made once per test session: under pytest-xdist the first worker
    to ask runs it into the session's shared temporary folder (the others wait on a lock),
    and every worker gets its own copy, which its tests may change."""
    worker = getattr(request.config, "workerinput", {}).get("workerid")
    if worker is None:  # one process: nothing to share
        out = tmp_path_factory.mktemp("quick")
        proc = run_script("--quick", "--out", str(out))
        assert proc.returncode == 0, proc.stdout + proc.stderr
        return out, proc.stdout
    shared = tmp_path_factory.getbasetemp().parent / "quick-run"  # this session's, common to its workers
    shared.mkdir(exist_ok=True)
    with open(shared / "lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not (shared / "stdout.txt").exists():
            proc = run_script("--quick", "--out", str(shared / "out"))
            assert proc.returncode == 0, proc.stdout + proc.stderr
            (shared / "stdout.txt").write_text(proc.stdout)
    out = tmp_path_factory.mktemp("quick") / "out"
    shutil.copytree(shared / "out", out)
    return out, (shared / "stdout.txt").read_text()


def test_quick_run_produces_everything(quick_run):
    out, stdout = quick_run
    for name in FIGURES + ["REPORT.md", "results.json", "results.npz", "run.json"]:
        assert (out / name).stat().st_size > 0, name
    results = strict_loads((out / "results.json").read_text())
    n = 42 * repro.DEFAULT_SEEDS
    assert results["complete"] and len(results["trials"]) == n == results["trials_expected"]
    assert results["key"] == res.settings_key(results["settings"])
    assert all(c["n"] + c["diverged"] == repro.DEFAULT_SEEDS for c in results["conditions"])
    assert [c["key"] for c in results["claims"]] == list("abcdef")
    report_md = (out / "REPORT.md").read_text()
    for c in results["claims"]:
        assert f"**{c['verdict']}**" in report_md and c["robustness"] in report_md
        assert c["seeds"] == repro.DEFAULT_SEEDS and all(p["ci"] is not None for p in c["parts"])
    assert " ± " in report_md
    with np.load(out / "results.npz") as data:
        assert data["Z"].shape[0] == n and np.iscomplexobj(data["Z"])
    assert "done in" in stdout and "seeds" in stdout


def test_report_tables_fitted_matrices_and_the_sampled_data_bias(quick_run, tmp_path):
    out, _ = quick_run
    results = strict_loads((out / "results.json").read_text())
    md = (out / "REPORT.md").read_text()
    assert "## Fitted M, B, K" in md
    assert "| condition | n | M rel. error | B rel. error | K rel. error | VAF [%] |" in md
    # the acquisition in words: an interval-mean fit is not read as a fit averaged over the seeds
    pair = "| pd-L1-F0-P1, instant samples: fit | err | pd-L1-F0-P1, interval-mean acquisition: fit | err |"
    assert "| element | true " + pair in md
    assert all({"fit_M", "fit_B", "fit_K", "fit_vaf"} <= t["metrics"].keys() for t in results["trials"])
    conds = {Condition(**c["condition"]): c for c in results["conditions"]}
    instant, mean = conds[Condition("pd", "pd", 1, 0, 1)], conds[Condition("pd", "pd", 1, 0, 1, "interval_mean")]
    assert instant["truth"] == true_matrices(1)
    # frictionless PD: the mass is well identified (6 s records, 1 Hz bins: a loose tolerance)
    np.testing.assert_allclose(instant["fit_M"], arm(1).mass, atol=0.1)
    assert instant["fit_M_rel_error"] < 0.05 and instant["fit_vaf"] > 95 and len(instant["fit_M_ci"]) == 2
    # instant samples bias the damping upwards; interval means take most of it away
    # each acquisition fitted with its own sampled-data model: no damping bias left in either
    # (the plain M s^2 + B s + K on instant samples gave B_11 over 1.3x the truth here)
    assert instant["fit_B_rel_error"] < 0.15 and mean["fit_B_rel_error"] < 0.15
    paragraph = next(line for line in md.splitlines() if line.startswith("Sampled-data bias"))
    assert f"with instant acquisition B is off by {100 * instant['fit_B_rel_error']:.1f}%" in paragraph
    assert f"with interval-mean acquisition B is off by {100 * mean['fit_B_rel_error']:.1f}%" in paragraph
    # results without fits (an older armimp_jax) still give a report, which says so
    for c in results["conditions"]:
        for k in [k for k in c if k.startswith("fit_") or k == "truth"]:
            del c[k]
    old = report.write_report(results, tmp_path, []).read_text()
    assert "hold no fitted matrices" in old and "Sampled-data bias" not in old


def test_the_tables_are_tidy_dataframes_and_csv_files_of_the_results(quick_run):
    import pandas as pd

    from armimp_jax.study.sweep import tables

    out, _ = quick_run
    results = strict_loads((out / "results.json").read_text())
    frames = repro.load_tables(out)
    dtypes = dict(conditions=ptables.CONDITION_DTYPES, claims=ptables.CLAIM_DTYPES, fits=ptables.FIT_DTYPES)
    for name, frame in frames.items():
        pd.testing.assert_frame_equal(tables.read_table(out / f"{name}.csv", dtypes[name]), frame, check_exact=True)
    conditions, claims, fits = frames["conditions"], frames["claims"], frames["fits"]
    assert len(conditions) == 42 and (conditions["n"] + conditions["diverged"] == repro.DEFAULT_SEEDS).all()
    for entry, (_, row) in zip(results["conditions"], conditions.iterrows(), strict=True):
        assert row["label"] == Condition(**entry["condition"]).label and row["phi_T_mean"] == entry["phi_T"]
        assert row["phi_T_ci_hi"] == pytest.approx(entry["phi_T"] + entry["phi_T_ci"], rel=1e-15)
        assert row["phi_21_mean"] == entry["phi_ij"][1][0]  # [output, input]
    assert list(claims["key"]) == list("abcdef")
    assert list(claims["verdict"]) == [c["verdict"] for c in results["claims"]]
    # long form: a row per condition, matrix and element, the truth beside the mean fit
    assert len(fits) == 42 * 3 * 4
    k21 = fits[(fits["label"] == "imbic-L3-F0-P1") & (fits["matrix"] == "K") & (fits["element"] == "21")]
    assert k21["true"].item() == arm(3).stiffness[1, 0] and k21["unit"].item() == "N/m"


def test_every_study_draws_one_signal_per_seed():
    """Common random numbers: the reproduction, the tuner and a sweep give seed s the same
    perturbation shape (scaled to the peak); another seed changes it."""
    from armimp_jax.paper import mhat_experiment as paper_tune
    from armimp_jax.presets import perturbation_peak

    settings = dataclasses.replace(TINY, base_seed=7)
    signals, _, attempt = repro.draw_perturbations(settings, 3, [1, 3])
    assert attempt == 0
    n = settings.n_samples
    tuner = paper_tune.seed_perturbations(7, [3], n, level=1)[0]
    swept = engine.Perturbations(7)(3, n, perturbation_peak(1))
    np.testing.assert_array_equal(signals[1], tuner)
    np.testing.assert_array_equal(signals[1], swept)
    np.testing.assert_allclose(signals[3], signals[1] * 4.5 / 2.25, rtol=1e-12)  # one shape, two peaks
    other = paper_tune.seed_perturbations(7, [4], n, level=1)[0]
    assert np.abs(other - tuner).max() > 0.1


def test_fit_metrics_recover_exact_matrices_and_give_nan_for_diverged_trials():
    f = np.linspace(0.5, 15.0, 30)
    z = np.stack([np.asarray(arm(loc).impedance(f)) for loc in (1, 3)] + [np.full((30, 2, 2), np.nan + 0j)])
    fits = fit_metrics(f, z, [1, 3, 2], acquisition="interval_mean")  # box-car means: M s^2 + B s + K exactly
    for fit, loc in zip(fits[:2], (1, 3)):
        a = arm(loc)
        np.testing.assert_allclose(fit["fit_M"], a.mass, atol=1e-9)
        np.testing.assert_allclose(fit["fit_B"], a.damping, atol=1e-9)
        np.testing.assert_allclose(fit["fit_K"], a.stiffness, atol=1e-7)
        assert max(fit[f"fit_{m}_rel_error"] for m in "MBK") < 1e-10 and fit["fit_vaf"] == pytest.approx(100.0)
    assert np.isnan(fits[2]["fit_B"]).all() and np.isnan(fits[2]["fit_vaf"])


@pytest.mark.slow  # about 13 s cold: every figure drawn again
def test_replot_redraws_from_saved_results(quick_run):
    out, _ = quick_run
    for name in FIGURES + ["REPORT.md"]:
        (out / name).unlink()
    proc = run_script("--replot", str(out))
    assert proc.returncode == 0, proc.stderr
    for name in FIGURES + ["REPORT.md"]:
        assert (out / name).exists(), name


def test_rerun_with_other_settings_is_refused_and_changes_nothing(quick_run):
    # The defect: --mhat 0.5 over a finished 0.25 run reported "mhat 0.5" over the 0.25 numbers.
    out, _ = quick_run
    before = (out / "results.json").read_bytes()
    one_line_error(
        run_script("--quick", "--mhat", "0.5", "--out", str(out)), f"{out} holds a run with mhat=0.25 (you asked 0.5)"
    )
    one_line_error(run_script("--quick", "--seconds", "8", "--out", str(out)), "seconds=6 (you asked 8)")
    assert (out / "results.json").read_bytes() == before


def test_a_folder_in_use_by_another_run_is_refused_at_once(tmp_path):
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys; from armimp_jax.study.runs.runfolder import RunLock\n"
         "with RunLock(sys.argv[1]):\n    print('held', flush=True); sys.stdin.read()", str(tmp_path)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )  # fmt: skip
    try:
        assert holder.stdout.readline().strip() == "held"
        proc = run_script("--quick", "--out", str(tmp_path))
    finally:
        holder.communicate("")
    one_line_error(proc, f"{tmp_path} is in use by another run: pid {holder.pid}")
    assert not (tmp_path / "run.json").exists()


@pytest.mark.slow  # 16 s cold (the suite's budget)
def test_resume_finishes_exactly_the_recorded_run_and_refuses_other_options(tmp_path, script):
    # The defects: a 4-condition run resumed into 21; "--frictions 0" resumed was marked
    # complete with trials missing; --resume ignored conflicting options.
    settings = dataclasses.replace(TINY, locations=(1,), frictions=(0,), perturbations=(1,))
    first = engine.run(settings, tmp_path, batch_size=3, stop_after_batches=1).computed
    assert len(first) == 1  # "interrupted" after the PD batch

    def resumed(*options):
        return script.settings_for(script.parse(["--resume", str(tmp_path), *options]), repro)

    for options, message in (
        (["--frictions", "0", "1"], "frictions=[0] (you asked [0,1])"),
        (["--mhat", "0.5"], "mhat=0.25 (you asked 0.5)"),
        (["--quick"], "noverlap=384 (you asked 768), nperseg=512 (you asked 1024)"),
        (["--seeds", "3"], "seeds=1 (you asked 3)"),
    ):
        with pytest.raises(res.ResultsError, match=re.escape(f"--resume {tmp_path}: that run has {message}")):
            resumed(*options)
    assert resumed("--frictions", "0", "--seconds", "2.2") == (settings, tmp_path)  # agreeing options are fine
    saved, out = resumed()
    results, _ = repro.aggregate(out)
    assert not results["complete"] and results["missing"] == ["imbic-L1-F0-P1-S0"]
    assert engine.run(saved, out).computed == ["imbic-L1-F0-P1-S0"]  # exactly the run's missing trial
    results, _ = repro.aggregate(out)
    assert results["complete"] and results["missing"] == [] and len(results["trials"]) == 2


@pytest.mark.slow  # about 9 s cold (the resume with its refusals stays fast)
def test_resume_computes_only_missing_trials_with_identical_numbers(tmp_path):
    settings = dataclasses.replace(TINY, locations=(1, 2), perturbations=(1,))
    full, part = tmp_path / "full", tmp_path / "part"
    all_ids = engine.run(settings, full, batch_size=3).computed
    first = engine.run(settings, part, batch_size=3, stop_after_batches=1).computed
    assert 0 < len(first) < len(all_ids)  # "interrupted" after one batch
    second = engine.run(settings, part, batch_size=3).computed
    assert sorted(first + second) == sorted(all_ids) and not set(first) & set(second)
    for c in settings.conditions:
        a = res.load_record(repro.trial_path(full, c, 0), settings=settings.trial_settings(c, 0))
        b = res.load_record(repro.trial_path(part, c, 0), settings=settings.trial_settings(c, 0))
        for k in a.arrays:
            np.testing.assert_array_equal(a.arrays[k], b.arrays[k])
        assert a.meta["metrics"] == b.meta["metrics"]
    # a corrupt record and one with altered numbers are named and recomputed, to the same numbers
    pd0, im0 = Condition("pd", "pd", 1, 0, 1), Condition("imbic", "imbic", 2, 2, 1)
    torn, altered = repro.trial_path(part, pd0, 0), repro.trial_path(part, im0, 0)
    torn.write_bytes(torn.read_bytes()[:500])
    with np.load(altered) as d:
        entries = {k: d[k] for k in d.files}
    entries["Z"] = entries["Z"] * 1.01
    np.savez(altered, **entries)
    warnings = []
    again = engine.run(settings, part, batch_size=3, warn=warnings.append).computed
    assert sorted(again) == sorted([trial_id(pd0, 0), trial_id(im0, 0)])
    assert len(warnings) == 2
    assert any(str(torn) in w and "truncated" in w for w in warnings)
    assert any(str(altered) in w and "checksum mismatch" in w for w in warnings)
    for c in (pd0, im0):  # recomputed in a batch of two, not three: the last bits may move
        a = res.load_record(repro.trial_path(full, c, 0)).arrays["Z"]
        np.testing.assert_allclose(res.load_record(repro.trial_path(part, c, 0)).arrays["Z"], a, rtol=1e-12)


def test_prepare_refuses_a_folder_holding_other_settings(tmp_path):
    def prepare(settings, out, resume):
        StudyRun.of(settings, out).prepare(settings.run_settings(), resume=resume, describe=settings.describe)

    prepare(TINY, tmp_path, resume=False)
    prepare(TINY, tmp_path, resume=True)  # the same settings: fine
    with pytest.raises(res.ResultsError, match=r"holds a run with seconds=2.2 \(you asked 3\)"):
        prepare(dataclasses.replace(TINY, seconds=3.0), tmp_path, resume=False)
    with pytest.raises(res.ResultsError, match="no run to resume"):
        prepare(TINY, tmp_path / "empty", resume=True)


def test_trial_keys_depend_on_what_changes_their_numbers():
    pd, im = Condition("pd", "pd", 1, 0, 1), Condition("imbic", "imbic", 1, 0, 1)
    other_mhat = dataclasses.replace(TINY, mhat=0.5)
    assert res.settings_key(TINY.trial_settings(pd, 0)) == res.settings_key(other_mhat.trial_settings(pd, 0))
    assert res.settings_key(TINY.trial_settings(im, 0)) != res.settings_key(other_mhat.trial_settings(im, 0))
    more = dataclasses.replace(TINY, seeds=5, frictions=(0,))  # the run changes, its trials do not
    assert res.settings_key(TINY.trial_settings(im, 0)) == res.settings_key(more.trial_settings(im, 0))
    for change in (dict(seconds=3.0), dict(substeps=5), dict(nperseg=256, noverlap=128), dict(base_seed=1)):
        assert res.settings_key(dataclasses.replace(TINY, **change).trial_settings(pd, 0)) != res.settings_key(
            TINY.trial_settings(pd, 0)
        )
    assert res.settings_key(TINY.trial_settings(pd, 0)) != res.settings_key(TINY.trial_settings(pd, 1))


@pytest.mark.parametrize(
    "args, message",
    [
        (["--quick", "--locations", "5"], "unknown location level"),
        (["--quick", "--frictions", "3"], "unknown friction level"),
        (["--quick", "--seeds", "0"], "--seeds must be >= 1"),
        (["--quick", "--seconds", "0.5"], "shorter than one Welch segment"),
        (["--quick", "--out", "/proc/forbidden"], "/proc/forbidden"),
        (["--quick", "--bogus"], "unrecognized arguments: --bogus"),
        (["--resume", "/nonexistent/run"], "--resume /nonexistent/run: no such folder"),
        (["--replot", "/nonexistent/run"], "--replot /nonexistent/run: no such folder"),
        (["--out", "a", "--resume", "b"], "give one of --out, --resume and --replot"),
    ],
)
def test_bad_arguments_fail_in_one_line_before_simulating(args, message):
    proc = run_script(*args)
    one_line_error(proc, message)
    assert "conditions x" not in proc.stdout  # nothing was simulated


def test_help_is_quick_and_names_the_default_seed_count(script):
    proc = run_script("--help")
    assert proc.returncode == 0 and proc.stderr == "" and f"(default {repro.DEFAULT_SEEDS})" in proc.stdout
    assert script.DEFAULT_SEEDS == repro.DEFAULT_SEEDS  # the script reads it before importing JAX
    assert script.QUICK == {k: getattr(repro.QUICK, k) for k in script.QUICK}


# --- diverged trials and strict JSON, on synthetic trial records ----------------------------


def _arrays(n_f=12):
    f = np.linspace(0.25, 15.0, n_f)
    return dict(
        f=f,
        Z=np.ones((n_f, 2, 2)) * (100 + 10j),
        coh_multiple_x=np.full((n_f, 2), 0.99),
        coh_partial_x=np.full((n_f, 2, 2), 0.9),
        coh_multiple_fh=np.full((n_f, 2), 0.99),
        coh_partial_fh=np.full((n_f, 2, 2), 0.9),
        coh_inputs=np.full(n_f, 0.1),
    )


def _metrics(phi, *, coh_low=0.99, coh_high=0.99, coh_med=0.99, rel=0.02, phase=2.0):
    return dict(
        phi_T=phi,
        phi_ij=[[phi / 2, phi / 4], [phi / 4, phi / 2]],
        rel_error=rel,
        phase_error_deg=phase,
        coh_multiple_x_min_low=coh_low,
        coh_multiple_x_min_high=coh_high,
        coh_multiple_x_median=coh_med,
        coh_multiple_fh_median=coh_med,
        coh_multiple_fh_min_low=coh_low,
        coh_multiple_fh_min_high=coh_high,
        coh_partial_x_min_low=coh_low,
        coh_partial_x_min_high=coh_high,
        input_coherence_max=0.1,
    )


NAN_METRICS = {k: (float("nan") if k != "phi_ij" else [[float("nan")] * 2] * 2) for k in _metrics(1.0)}


def _write_trial(out, settings, cond, seed, metrics, *, diverged=False):
    meta = dict(
        id=trial_id(cond, seed),
        condition=dataclasses.asdict(cond),
        seed=seed,
        perturbation_attempt=0,
        input_coherence_max=0.1,
        diverged=diverged,
        diverged_at=100 if diverged else -1,
        batch_wall_s=0.0,
        batch_size=1,
        metrics=NAN_METRICS if diverged else metrics,
    )
    arrays = _arrays()
    if diverged:
        arrays["Z"] = arrays["Z"] * np.nan
    res.save_record(
        repro.trial_path(out, cond, seed), settings=settings.trial_settings(cond, seed), arrays=arrays, meta=meta
    )


def test_diverged_trials_are_counted_shown_and_left_out_of_means_and_claims(tmp_path):
    settings = dataclasses.replace(TINY, seeds=3, locations=(1, 2, 3, 4), perturbations=(1, 3))
    StudyRun.of(settings, tmp_path).prepare(settings.run_settings(), extra=settings.run_extra())
    for c in settings.conditions:
        for s in range(3):
            phi = (200.0 if c.friction == 0 else 3000.0) + 10 * s if c.experiment == "pd" else 200.0 + 5 * s
            if c == Condition("pd", "pd", 1, 1, 1):
                _write_trial(tmp_path, settings, c, s, _metrics(phi), diverged=True)  # every trial diverged
            elif c == Condition("pd", "pd", 1, 0, 1) and s == 2:
                _write_trial(tmp_path, settings, c, s, _metrics(1e9), diverged=True)  # one of three
            else:
                _write_trial(tmp_path, settings, c, s, _metrics(phi, coh_low=0.3 if c.friction else 0.99))
    results, arrays = repro.aggregate(tmp_path)
    text = (tmp_path / "results.json").read_text()
    assert "NaN" not in text and "Infinity" not in text
    assert strict_loads(text) == json.loads(res.strict_json_dumps(results))
    conds = {Condition(**c["condition"]): c for c in results["conditions"]}
    dead, some = conds[Condition("pd", "pd", 1, 1, 1)], conds[Condition("pd", "pd", 1, 0, 1)]
    assert dead["n"] == 0 and dead["diverged"] == 3 and dead["phi_T"] is None and dead["phi_T_ci"] is None
    assert some["n"] == 2 and some["diverged"] == 1 and some["diverged_seeds"] == [2]
    assert some["phi_T"] == pytest.approx(205.0)  # the diverged 1e9 is not in the mean
    assert some["phi_T_ci"] == pytest.approx(mean_ci([200.0, 210.0])[2])
    assert len(results["diverged"]) == 4 and results["complete"]
    claims = {c["key"]: c for c in results["claims"]}
    for key in "bce":  # they read the all-diverged condition
        assert "pd-L1-F1-P1" in claims[key]["ours"] and claims[key]["left_out"] == ["pd-L1-F1-P1"]
    assert claims["a"]["left_out"] == [] and "left out (a trial the claim needs diverged)" in claims["a"]["robustness"]
    assert claims["a"]["seeds"] == 2  # seed 2 lost its frictionless PD trial
    # the report and the figures that read condition means draw them without the missing numbers
    figures = [
        plots.phi_bars(results, tmp_path / "pd_phi.png", experiment="pd"),
        plots.bode_figure(results, arrays, tmp_path / "pd_bode.png", experiment="pd"),  # seed 0 of F1 diverged
    ]
    md = report.write_report(results, tmp_path, figures).read_text()
    assert "4 trial(s) diverged" in md and "| 1 | 1 | 1 | 0 | — |" in md


# --- the claims rules and their statistics ---------------------------------------------------


def _synthetic(paper_like: bool, jitter: float = 0.0):
    s = {}
    for p in (1, 2, 3):
        s[Condition("pd", "pd", 1, 0, p)] = _metrics(200.0 * (1 + jitter))
        for fr in (1, 2):
            if paper_like:
                s[Condition("pd", "pd", 1, fr, p)] = _metrics(4000.0 - 100 * p, coh_low=0.2, rel=0.9, phase=60)
            else:  # friction barely matters, and larger perturbations fix it
                s[Condition("pd", "pd", 1, fr, p)] = _metrics(900.0 / p**2, coh_low=0.95, rel=0.1, phase=5)
    for loc in (1, 2, 3, 4):
        for fr in (0, 1, 2):
            if paper_like:
                s[Condition("imbic", "imbic", loc, fr, 1)] = _metrics(
                    (200.0 + 20 * fr + 10 * loc) * (1 + jitter), coh_low=0.95
                )
            else:
                s[Condition("imbic", "imbic", loc, fr, 1)] = _metrics(
                    200.0 * loc**2 * (1 + 5 * fr), coh_low=0.3, coh_med=0.5
                )
    return s


def test_claims_are_judged_from_the_numbers():
    good = {c.key: c.verdict for c in evaluate_claims(_synthetic(True))}
    assert good == dict.fromkeys("abcdef", "reproduced")
    bad = {c.key: c.verdict for c in evaluate_claims(_synthetic(False))}
    assert bad == dict(a="reproduced", b="not", c="not", d="not", e="not", f="not")
    partial = _synthetic(True)
    partial[Condition("pd", "pd", 1, 2, 3)] = _metrics(1000.0, coh_low=0.2, rel=0.5, phase=40)  # helps at friction 2
    partial[Condition("imbic", "imbic", 4, 1, 1)] = _metrics(600.0, coh_low=0.85)  # one weak location
    verdicts = {c.key: c.verdict for c in evaluate_claims(partial)}
    assert verdicts["c"] == "partly" and verdicts["d"] == "partly" and verdicts["f"] == "partly"
    assert verdicts["e"] == "partly"  # slightly above frictionless fails at location 4, still far below PD
    assert all(c.verdict == "n/a" for c in evaluate_claims({}))


def _ensemble(per_seed):
    """Trial records of ``{seed: {Condition: metrics}}`` -> (condition summary, seed summaries)."""
    metas = [
        dict(condition=dataclasses.asdict(c), seed=sd, diverged=False, metrics=m)
        for sd, ms in per_seed.items()
        for c, m in ms.items()
    ]
    return condition_summary(metas), seed_summaries(metas)


def test_mean_ci_is_the_t_interval_of_the_mean():
    mean, sd, half = mean_ci([1.0, 2.0, 3.0])
    assert mean == 2.0 and sd == 1.0 and half == pytest.approx(4.302652729911275 / np.sqrt(3))
    assert mean_ci([5.0])[2] is None and mean_ci([5.0])[1] == 0.0
    m, _, h = mean_ci([[1.0, 10.0], [3.0, 10.0]])  # elementwise for arrays
    np.testing.assert_allclose(m, [2.0, 10.0])
    np.testing.assert_allclose(h, [12.706204736174698, 0.0])


def test_claims_on_a_seed_ensemble_say_how_robust_they_are():
    summary, seeds = _ensemble({s: _synthetic(True, jitter=0.01 * s) for s in range(3)})
    claims = {c.key: c for c in evaluate_claims(summary, seeds)}
    for c in claims.values():
        assert c.verdict == "reproduced" and c.robust and c.seeds == 3
        assert c.robustness == "reproduced on 3/3 seeds; every deciding rule also holds on its 95% CI over the seeds"
    # one seed on which friction does not hurt PD: (b) still holds on the means, but not robustly
    mixed = {s: _synthetic(True) for s in range(3)}
    mixed[2] = _synthetic(True) | {k: v for k, v in _synthetic(False).items() if k.experiment == "pd" and k.friction}
    summary, seeds = _ensemble(mixed)
    b = next(c for c in evaluate_claims(summary, seeds) if c.key == "b")
    assert not b.robust and b.seed_verdicts["not"] == 1
    assert b.robustness.startswith(f"{b.verdict} on ") and "/3 seeds" in b.robustness and "95% CI of" in b.robustness
    # one seed: a verdict, but no interval is claimed
    summary, seeds = _ensemble({0: _synthetic(True)})
    for c in evaluate_claims(summary, seeds):
        assert c.robustness == "1 seed: no interval" and c.robust is None
        assert all(p["ci"] is None for p in c.parts)
