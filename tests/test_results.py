"""Saved results: strict JSON, settings keys, atomic writes, checked records, the run lock."""

import json
import os
import pathlib
import socket
import subprocess
import sys

import numpy as np
import pytest

from armimp_jax import __version__
from armimp_jax.study.runs import results as res
from armimp_jax.study.runs.runfolder import RunLock

ROOT = pathlib.Path(__file__).resolve().parents[1]


def _strict_loads(text):
    def refuse(token):
        raise AssertionError(f"non-standard JSON constant {token}")

    return json.loads(text, parse_constant=refuse)


def test_strict_json_writes_null_for_nan_and_plain_numbers_for_numpy():
    obj = dict(
        a=float("nan"),
        b=[float("inf"), -np.inf, 1.5],
        c=np.float32(2.5),
        d=np.int64(3),
        e=np.array([[1.0, np.nan], [2.0, 3.0]]),
        f=(1, 2),
        g=np.bool_(True),
        h=pathlib.Path("x/y"),
    )
    text = res.strict_json_dumps(obj)
    assert "NaN" not in text and "Infinity" not in text
    assert _strict_loads(text) == dict(
        a=None, b=[None, None, 1.5], c=2.5, d=3, e=[[1.0, None], [2.0, 3.0]], f=[1, 2], g=True, h="x/y"
    )
    with pytest.raises(TypeError, match="complex"):
        res.strict_json_dumps(dict(z=1 + 2j))


def test_settings_key_is_canonical_and_includes_the_version():
    a = dict(seconds=6.0, welch=dict(nperseg=1024, noverlap=768), levels=[1, 2])
    b = dict(levels=[1, 2], welch=dict(noverlap=768, nperseg=1024), seconds=6)  # other order, 6 for 6.0
    assert res.settings_key(a) == res.settings_key(b)
    assert res.settings_key(a) == res.settings_key(res.stamped(a)) and res.stamped(a)["armimp_jax"] == __version__
    assert res.settings_key(a) != res.settings_key(dict(a, seconds=8.0))
    assert res.settings_key(a) != res.settings_key(dict(a, levels=[2, 1]))
    assert res.settings_key(dict(flag=True)) != res.settings_key(dict(flag=1))
    assert res.settings_key(a) != res.settings_key(dict(a, armimp_jax="0.0.1"))  # another package version


def test_the_version_is_stated_once_in_pyproject():
    import tomllib

    stated = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]
    assert __version__ == res.package_version() == stated
    assert res.stamped({})["armimp_jax"] == stated


def test_a_record_is_stamped_with_the_version_this_process_imported(monkeypatch):
    # a reinstall under a running study changes the installed metadata, not the code it runs
    import importlib.metadata

    monkeypatch.setattr(importlib.metadata, "version", lambda name: "99.0.0")
    assert res.package_version() == __version__ != "99.0.0"
    assert res.stamped({})["armimp_jax"] == __version__


def test_describe_difference_is_one_line_naming_each_setting():
    saved = res.stamped(dict(seconds=6.0, mhat=0.25, welch=dict(nperseg=1024), frictions=[0, 1, 2]))
    wanted = dict(seconds=8.0, mhat=0.25, welch=dict(nperseg=512), frictions=[0], extra=1)
    text = res.describe_difference(saved, wanted)
    assert "\n" not in text
    assert text == (
        "extra=(unset) (you asked 1), frictions=[0,1,2] (you asked [0]), seconds=6 (you asked 8), "
        "welch.nperseg=1024 (you asked 512)"
    )
    assert res.describe_difference(saved, dict(saved)) == "no difference"


def test_atomic_write_leaves_the_old_file_when_the_write_fails(tmp_path, monkeypatch):
    path = tmp_path / "r.json"
    res.atomic_write_json(path, dict(x=1))
    assert _strict_loads(path.read_text()) == dict(x=1)

    def broken(*_):
        raise OSError("disk full")

    monkeypatch.setattr(res.os, "replace", broken)
    with pytest.raises(OSError, match="disk full"):
        res.atomic_write_json(path, dict(x=2))
    assert _strict_loads(path.read_text()) == dict(x=1)
    assert [p.name for p in tmp_path.iterdir()] == ["r.json"]  # no temporary file left behind


def test_atomic_npz_writes_savez_bytes_through_a_unique_temporary_file(tmp_path, monkeypatch):
    """The one npz writer: what ``np.savez`` writes, renamed into place from a temporary file
    of its own in the same folder (two writers never share a temporary name)."""
    arrays = dict(f_delta=np.arange(6.0).reshape(3, 2), fs_hz=1000.0, duty=np.float64(0.25))
    temporaries = []
    replace = res.os.replace

    def spy(src, dst):
        temporaries.append(pathlib.Path(src))
        replace(src, dst)

    monkeypatch.setattr(res.os, "replace", spy)
    for _ in range(2):
        assert res.atomic_write_npz(tmp_path / "p.npz", **arrays) == tmp_path / "p.npz"
    expected = tmp_path / "expected.npz"
    np.savez(expected, **arrays)
    assert (tmp_path / "p.npz").read_bytes() == expected.read_bytes()
    assert len(set(temporaries)) == 2 and all(t.parent == tmp_path for t in temporaries)
    with np.load(tmp_path / "p.npz") as z:
        np.testing.assert_array_equal(z["f_delta"], arrays["f_delta"])
        assert float(z["fs_hz"]) == 1000.0


def test_read_json_refuses_nan_and_names_the_file(tmp_path):
    path = tmp_path / "bad.json"
    path.write_text('{"a": NaN}')
    with pytest.raises(res.ResultsError, match=r"bad\.json: not valid JSON"):
        res.read_json(path)
    with pytest.raises(res.ResultsError, match="missing.json: no such file"):
        res.read_json(tmp_path / "missing.json")


SETTINGS = dict(seconds=6.0, seed=3)
ARRAYS = dict(Z=np.arange(8.0).reshape(2, 2, 2) * (1 + 2j), f=np.linspace(0.1, 15, 2), ids=np.array(["a", "bb"]))


def test_record_round_trip(tmp_path):
    path = tmp_path / "t.npz"
    key = res.save_record(path, settings=SETTINGS, arrays=ARRAYS, meta=dict(phi=float("nan"), n=2))
    rec = res.load_record(path, settings=SETTINGS)
    assert rec.key == key == res.settings_key(SETTINGS)
    assert rec.settings == res.stamped(SETTINGS) and rec.meta == dict(phi=None, n=2)
    for k, v in ARRAYS.items():
        np.testing.assert_array_equal(rec.arrays[k], v)
    assert [p.name for p in tmp_path.iterdir()] == ["t.npz"]


def test_record_that_is_truncated_altered_or_of_other_settings_is_named(tmp_path):
    path = tmp_path / "t.npz"
    res.save_record(path, settings=SETTINGS, arrays=ARRAYS, meta=dict(phi=1.0))
    data = path.read_bytes()

    path.write_bytes(data[: len(data) // 2])  # torn
    with pytest.raises(res.ResultsError, match=r"t\.npz: unreadable, truncated or not an npz file"):
        res.load_record(path)

    _restore(path, data)  # altered numbers, header kept
    with np.load(path) as d:
        entries = {k: d[k] for k in d.files}
    entries["Z"] = entries["Z"] * 1.001
    np.savez(path, **entries)
    with pytest.raises(res.ResultsError, match=r"t\.npz: checksum mismatch"):
        res.load_record(path)

    _restore(path, data)  # altered metadata (the scores), digest kept
    with np.load(path) as d:
        entries = {k: d[k] for k in d.files}
    header = json.loads(str(entries[res.RECORD_ENTRY]))
    header["meta"]["phi"] = 0.5
    entries[res.RECORD_ENTRY] = np.array(json.dumps(header))
    np.savez(path, **entries)
    with pytest.raises(res.ResultsError, match="checksum mismatch"):
        res.load_record(path)

    _restore(path, data)
    with pytest.raises(res.ResultsError, match=r"made with other settings: seconds=6 \(you asked 8\)"):
        res.load_record(path, settings=dict(SETTINGS, seconds=8.0))

    np.savez(path, Z=ARRAYS["Z"])
    with pytest.raises(res.ResultsError, match="not a results record"):
        res.load_record(path)
    with pytest.raises(res.ResultsError, match="no such file"):
        res.load_record(tmp_path / "none.npz")


def _restore(path, data):
    path.write_bytes(data)
    return path


def test_run_lock_is_exclusive_reentrant_and_released(tmp_path):
    folder = tmp_path / "run"
    with RunLock(folder) as lock:
        info = json.loads((folder / ".lock").read_text())
        assert info["pid"] == os.getpid() and info["host"] == socket.gethostname()
        with RunLock(folder):  # the holder may take it again
            pass
        assert (folder / ".lock").exists() and lock.holder()["pid"] == os.getpid()
    assert not (folder / ".lock").exists()


def _fake_lock(folder, pid, host=None):
    folder.mkdir(parents=True, exist_ok=True)
    info = dict(pid=pid, host=host or socket.gethostname(), started="2026-01-01T00:00:00+00:00")
    (folder / ".lock").write_text(json.dumps(info))


def test_run_lock_refuses_a_folder_held_by_a_live_process(tmp_path):
    _fake_lock(tmp_path, os.getppid())  # the test runner's parent: alive
    with pytest.raises(res.ResultsError) as err:
        with RunLock(tmp_path):
            pass
    assert f"{tmp_path} is in use by another run: pid {os.getppid()} on {socket.gethostname()}" in str(err.value)
    assert "\n" not in str(err.value)
    assert (tmp_path / ".lock").exists()  # someone else's lock is left alone


def test_run_lock_takes_over_a_lock_of_a_dead_process_but_not_of_another_host(tmp_path):
    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait()
    _fake_lock(tmp_path / "a", gone.pid)
    with RunLock(tmp_path / "a"):
        assert json.loads((tmp_path / "a" / ".lock").read_text())["pid"] == os.getpid()
    _fake_lock(tmp_path / "b", os.getpid(), host="elsewhere.example")
    with pytest.raises(res.ResultsError, match="pid .* on elsewhere.example .* delete the lock file"):
        with RunLock(tmp_path / "b"):
            pass


HOLD = """
import sys
from armimp_jax.study.runs.runfolder import RunLock
with RunLock(sys.argv[1]):
    print("held", flush=True)
    sys.stdin.read()
"""


def test_run_lock_held_by_another_process_and_freed_when_it_ends(tmp_path):
    holder = subprocess.Popen(
        [sys.executable, "-c", HOLD, str(tmp_path)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(res.ResultsError, match=f"in use by another run: pid {holder.pid} "):
            with RunLock(tmp_path):
                pass
    finally:
        holder.communicate("")
    assert holder.returncode == 0 and not (tmp_path / ".lock").exists()
    with RunLock(tmp_path):  # free again: taken at once (a held lock raises, it never waits)
        pass
