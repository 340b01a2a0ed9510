"""armimp_jax.study.runs.runfolder: the one run-folder protocol (run.json, refusals naming the
difference, resume, edited settings, other studies, trial status, the lock), on plain dicts."""

import json
import re

import numpy as np
import pytest

from armimp_jax.study.runs import results as res
from armimp_jax.study.runs.runfolder import RUN_FILE, StudyRun

SETTINGS = dict(seconds=6.0, welch=dict(nperseg=1024), frictions=[0, 1])


def folder(path, **kw):
    return StudyRun(path, kind="test", format=3, **kw)


def test_prepare_writes_run_json_once_and_goes_on_with_the_same_settings(tmp_path):
    run = folder(tmp_path / "run").prepare(SETTINGS, extra=dict(versions="v", wall_s=0.0))
    on_disk = json.loads((tmp_path / "run" / RUN_FILE).read_text())
    assert on_disk == run and list(on_disk) == ["kind", "format", "settings", "key", "versions", "wall_s"]
    assert run["kind"] == "test" and run["format"] == 3 and run["key"] == res.settings_key(SETTINGS)
    assert (tmp_path / "run" / "trials").is_dir()
    same = dict(SETTINGS, seconds=6)  # 6 and 6.0 are one setting
    assert folder(tmp_path / "run").prepare(same, resume=True) == run
    assert folder(tmp_path / "run").saved_settings() == res.stamped(SETTINGS)
    folder(tmp_path / "bare", records=None).prepare(SETTINGS)
    assert [p.name for p in (tmp_path / "bare").iterdir()] == [RUN_FILE]


def test_other_settings_and_a_missing_run_are_refused_naming_the_difference(tmp_path):
    f = folder(tmp_path, noun="widget run")
    with pytest.raises(res.ResultsError, match=f"{tmp_path} holds no widget run to resume"):
        f.prepare(SETTINGS, resume=True)
    f.prepare(SETTINGS)
    with pytest.raises(res.ResultsError) as err:
        f.prepare(dict(SETTINGS, seconds=8.0, frictions=[0]))
    assert str(err.value) == (
        f"{tmp_path} holds a widget run with frictions=[0,1] (you asked [0]), seconds=6 (you asked 8): use another "
        f"output folder (--out), or resume it with its own settings (--resume {tmp_path})"
    )
    with pytest.raises(res.ResultsError, match=re.escape(f"--resume {tmp_path}: that run has seconds=6 (you asked 8)")):
        f.check_resume(f.saved_settings(), dict(SETTINGS, seconds=8.0))
    f.check_resume(f.saved_settings(), dict(SETTINGS))  # agreeing options are fine


def test_run_json_of_another_study_format_or_edited_settings_is_refused(tmp_path):
    f = folder(tmp_path)
    f.prepare(SETTINGS)
    with pytest.raises(res.ResultsError, match=r"not the run.json of a run .*kind 'test', format 3; expected 'other'"):
        StudyRun(tmp_path, kind="other", format=3).read()
    with pytest.raises(res.ResultsError, match="format 3; expected 'test', format 4"):
        StudyRun(tmp_path, kind="test", format=4).read()
    run = json.loads(f.run_file.read_text())
    f.run_file.write_text(json.dumps(run | dict(settings=dict(run["settings"], seconds=7.0))))
    with pytest.raises(res.ResultsError, match="its settings were edited after the run"):
        f.read()
    del run["kind"]  # written before run.json named its study: read as this study's, by its format
    f.run_file.write_text(json.dumps(run))
    assert f.read()["key"] == res.settings_key(SETTINGS)
    with pytest.raises(res.ResultsError, match="no such folder"):
        folder(tmp_path / "none").read()


def test_update_changes_what_a_run_adds_never_its_settings(tmp_path):
    f = folder(tmp_path)
    f.prepare(SETTINGS, extra=dict(wall_s=1.5))
    assert f.update(wall_s=4.0)["wall_s"] == 4.0 and f.read()["wall_s"] == 4.0
    with pytest.raises(ValueError, match="not"):
        f.update(settings={})


def test_status_save_and_open(tmp_path):
    f = folder(tmp_path)
    trials = [(s, f"t{s}", dict(SETTINGS, seed=s)) for s in range(3)]
    with f.open(SETTINGS, trials) as (done, todo):
        assert (done, todo) == ([], [0, 1, 2])
        assert (tmp_path / ".lock").exists()  # held for as long as the run goes on
        for s, record_id, settings in trials[:2]:
            f.save(record_id, settings=settings, arrays=dict(x=np.full(3, s)))
    assert not (tmp_path / ".lock").exists()
    torn = f.record_path("t1")
    assert torn == tmp_path / "trials" / "t1.npz"
    torn.write_bytes(torn.read_bytes()[:100])
    warnings = []
    records, todo = f.status(trials, warn=warnings.append, note="left out")
    assert list(records) == [0] and todo == [1, 2]
    assert len(warnings) == 1 and str(torn) in warnings[0] and warnings[0].endswith("; left out")
    np.testing.assert_array_equal(records[0].arrays["x"], [0, 0, 0])
    with f.open(SETTINGS, trials, resume=True, warn=lambda _: None) as (done, todo):
        assert (done, todo) == ([0], [1, 2])
    with pytest.raises(res.ResultsError, match="holds a run with seconds=6"):
        with f.open(dict(SETTINGS, seconds=9.0), trials):
            pass
