"""The reproduction script end to end (quick mode), replot, resume, and the claims rules."""

import json
import pathlib
import subprocess
import sys

import numpy as np
import pytest

from armimp_jax.paper import reproduce as repro
from armimp_jax.paper.claims import Condition, evaluate_claims, paper_conditions

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
TINY = repro.ReproSettings(seconds=2.2, substeps=4, nperseg=512, noverlap=384)


def run_script(*args):
    return subprocess.run([sys.executable, str(SCRIPT), *args], capture_output=True, text=True, cwd=ROOT, timeout=900)


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("quick")
    proc = run_script("--quick", "--out", str(out))
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return out, proc


def test_quick_run_produces_everything(quick_run):
    out, proc = quick_run
    for name in FIGURES + ["REPORT.md", "results.json", "results.npz", "run.json"]:
        assert (out / name).stat().st_size > 0, name
    results = json.loads((out / "results.json").read_text())
    assert results["complete"] and len(results["trials"]) == 42
    assert [c["key"] for c in results["claims"]] == list("abcdef")
    report = (out / "REPORT.md").read_text()
    for c in results["claims"]:
        assert f"**{c['verdict']}**" in report
    with np.load(out / "results.npz") as data:
        assert data["Z"].shape[0] == 42 and np.iscomplexobj(data["Z"])
    assert "done in" in proc.stdout


def test_replot_redraws_from_saved_results(quick_run):
    out, _ = quick_run
    for name in FIGURES + ["REPORT.md"]:
        (out / name).unlink()
    proc = run_script("--replot", str(out))
    assert proc.returncode == 0, proc.stderr
    for name in FIGURES + ["REPORT.md"]:
        assert (out / name).exists(), name


def test_resume_computes_only_missing_trials_with_identical_numbers(tmp_path):
    import jax

    jax.config.update("jax_enable_x64", True)
    conditions = [c for c in paper_conditions(ablation=False) if c.location in (1, 2) and c.perturbation == 1]
    full, part = tmp_path / "full", tmp_path / "part"
    for out in (full, part):
        repro.prepare_output(out, TINY, resume=False)
    all_ids = repro.run_reproduction(TINY, full, conditions=conditions, batch_size=3)
    first = repro.run_reproduction(TINY, part, conditions=conditions, batch_size=3, stop_after_batches=1)
    assert 0 < len(first) < len(all_ids)  # "interrupted" after one batch
    repro.prepare_output(part, TINY, resume=True)
    second = repro.run_reproduction(TINY, part, conditions=conditions, batch_size=3)
    assert sorted(first + second) == sorted(all_ids) and not set(first) & set(second)
    for tid in all_ids:
        a = np.load(full / "trials" / f"{tid}.npz")
        b = np.load(part / "trials" / f"{tid}.npz")
        for k in a.files:
            np.testing.assert_array_equal(a[k], b[k])
        ma = json.loads((full / "trials" / f"{tid}.json").read_text())["metrics"]
        mb = json.loads((part / "trials" / f"{tid}.json").read_text())["metrics"]
        assert ma == mb


def test_resume_refuses_different_settings(tmp_path):
    repro.prepare_output(tmp_path, TINY, resume=False)
    with pytest.raises(ValueError, match="differ from these"):
        repro.prepare_output(
            tmp_path, repro.ReproSettings(seconds=3.0, substeps=4, nperseg=512, noverlap=384), resume=True
        )


@pytest.mark.parametrize(
    "args, message",
    [
        (["--quick", "--locations", "5"], "unknown location level"),
        (["--quick", "--frictions", "3"], "unknown friction level"),
        (["--quick", "--seeds", "0"], "seeds must be >= 1"),
        (["--quick", "--seconds", "0.5"], "shorter than one Welch segment"),
        (["--quick", "--out", "/proc/forbidden"], "not writable"),
    ],
)
def test_bad_arguments_fail_before_simulating(args, message):
    proc = run_script(*args)
    assert proc.returncode != 0 and message in proc.stderr, proc.stderr
    assert "conditions x" not in proc.stdout  # nothing was simulated


def _metrics(phi, *, coh_low=0.99, coh_high=0.99, coh_med=0.99, rel=0.02, phase=2.0):
    return dict(
        phi_T=phi,
        rel_error=rel,
        phase_error_deg=phase,
        coh_multiple_x_min_low=coh_low,
        coh_multiple_x_min_high=coh_high,
        coh_multiple_x_median=coh_med,
        coh_multiple_fh_median=coh_med,
    )


def _synthetic(paper_like: bool):
    s = {}
    for p in (1, 2, 3):
        s[Condition("pd", "pd", 1, 0, p)] = _metrics(200.0)
        for fr in (1, 2):
            if paper_like:
                s[Condition("pd", "pd", 1, fr, p)] = _metrics(4000.0 - 100 * p, coh_low=0.2, rel=0.9, phase=60)
            else:  # friction barely matters, and larger perturbations fix it
                s[Condition("pd", "pd", 1, fr, p)] = _metrics(900.0 / p**2, coh_low=0.95, rel=0.1, phase=5)
    for loc in (1, 2, 3, 4):
        for fr in (0, 1, 2):
            if paper_like:
                s[Condition("imbic", "imbic", loc, fr, 1)] = _metrics(200.0 + 20 * fr + 10 * loc, coh_low=0.95)
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
