"""The statistics tier's report (tests/validation.py) is written from the figures its tests saved:
every figure with the run that measured it and its test's outcome, a partial run keeping the rest."""

import json

import pytest
import validation


def _figure(folder, name, test, **extra):
    run = dict(date="2026-01-01 00:00 UTC", armimp_jax="9.9.9", jax="0.0", host="x86_64, 2 cores", test=test) | extra
    (folder / f"{name}.json").write_text(json.dumps(dict(coverage=0.951, rms_z=1.02, outside=[], run=run)))


def test_the_report_lists_every_figure_with_its_run_and_outcome(tmp_path, monkeypatch):
    figures = tmp_path / "figures"
    monkeypatch.setenv("ARMIMP_STATS_OUT", str(figures))
    report = tmp_path / "validation.md"
    assert validation.write({"t.py::a": "passed"}, report) is None and not report.exists()  # no figure yet
    figures.mkdir()
    _figure(figures, "cov-now", "t.py::a")
    _figure(figures, "cov-before", "t.py::b", outcome="failed")  # an earlier run's figure and outcome
    assert validation.write({"t.py::a": "passed"}, report) == report
    text = report.read_text()
    assert "| cov-now | passed | 2026-01-01 00:00 UTC | 9.9.9 | x86_64, 2 cores |" in text
    assert "| cov-before | failed |" in text and "- coverage: 0.951" in text and "outside its band: none" in text
    assert json.loads((figures / "cov-now.json").read_text())["run"]["outcome"] == "passed"  # kept for later runs
    # a later partial run that measures only the other figure keeps this one's outcome
    validation.write({"t.py::b": "passed"}, report)
    assert "| cov-now | passed |" in report.read_text() and "| cov-before | passed |" in report.read_text()


def test_the_report_reads_back_words_lists_and_nested_figures(tmp_path, monkeypatch):
    figures = tmp_path / "figures"
    figures.mkdir()
    monkeypatch.setenv("ARMIMP_STATS_OUT", str(figures))
    run = dict(date="2026-01-01 00:00 UTC", armimp_jax="9.9.9", test="t.py::a")
    figure = dict(ours="lowest (x and F_h, over levels): 0.99 deg", arm={"1": dict(threshold=0.2761)}, per=[0.9, 1.0])
    (figures / "fit-imbic-0.3Nm-instant.json").write_text(json.dumps(dict(figure, run=run)))
    report = tmp_path / "validation.md"
    validation.write({"t.py::a": "passed"}, report)
    read = validation.read(report)["fit-imbic-03nm-instant"]
    assert read["outcome"] == "passed" and read["name"] == "fit-imbic-0.3Nm-instant"
    assert read["figures"] == {"ours": figure["ours"], "arm.1.threshold": "0.2761", "per": "0.9, 1"}
    (figures / "fit-imbic-03Nm-instant.json").write_text(json.dumps(dict(figure, run=run)))  # one anchor, two names
    validation.write({}, report)
    with pytest.raises(ValueError, match="share an anchor"):
        validation.read(report)
