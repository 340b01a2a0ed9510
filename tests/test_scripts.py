"""Every script in sweeps/ answers ``--help`` before it imports JAX (its options are parsed
first: checked in a process where JAX cannot be imported, not with a clock), and
numba_baseline.py says what it needs when numba is missing."""

import ast
import io
import os
import pathlib
import subprocess
import sys

import pytest
from helpers import env_without_jax

ROOT = pathlib.Path(__file__).resolve().parents[1]
SCRIPTS = sorted((ROOT / "sweeps").glob("*.py"))


def run(*args, **kwargs):
    return subprocess.run([sys.executable, *map(str, args)], capture_output=True, text=True, cwd=ROOT, **kwargs)


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: p.name)
def test_help_answers_before_jax_is_imported(script, tmp_path):
    proc = run(script, "--help", timeout=120, env=env_without_jax(tmp_path))
    assert proc.returncode == 0, f"{script.name} --help: {proc.stderr}"
    assert "usage:" in proc.stdout


@pytest.mark.parametrize("name", ["reproduce_paper", "tune_mhat", "sweep", "friction_threshold"])
def test_an_unknown_option_gets_one_line_under_the_script_s_own_name(name):
    proc = run(ROOT / "sweeps" / f"{name}.py", "--bogus", timeout=60)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == [f"{name}: error: unrecognized arguments: --bogus"]


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: p.name)
def test_scripts_are_shells_on_the_public_library(script):
    """A script imports the library's public modules (no ``armimp_jax._private``), no other
    script (nothing from its own folder, nothing on ``sys.path`` it put there) and loads no
    file by path (no ``importlib``)."""
    tree = ast.parse(script.read_text())
    imported = [a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names]
    imported += [n.module or "" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)]
    private = [m for m in imported if m.startswith("armimp_jax.") and any(p.startswith("_") for p in m.split(".")[1:])]
    assert not private, private
    assert not any(m.startswith("importlib") for m in imported), imported
    siblings = {p.stem for p in (ROOT / "sweeps").glob("*.py")}
    assert not [m for m in imported if m.split(".")[0] in siblings], imported
    assert "sys.path" not in script.read_text()


def test_the_scripts_are_at_most_2500_lines():
    assert sum(len(p.read_text().splitlines()) for p in SCRIPTS) <= 2500


def test_numba_baseline_without_numba(tmp_path):
    """A stand-in ``numba`` package that fails to import, as on a machine without the bench extra."""
    (tmp_path / "numba").mkdir()
    (tmp_path / "numba" / "__init__.py").write_text("raise ImportError('numba is not installed')\n")
    env = dict(os.environ, PYTHONPATH=str(tmp_path))
    script = ROOT / "sweeps" / "numba_baseline.py"
    assert run(script, "--help", env=env, timeout=60).returncode == 0
    proc = run(script, env=env, timeout=60)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == ["numba_baseline: error: needs numba (pip install -e '.[bench]')"]


def test_the_progress_bar_leaves_compilation_out_and_ends_at_100(monkeypatch):
    """Two batches of 2 trials, 3 chunks each: the first chunk of a batch (compilation) is
    left out of the rate, chunk ends that finish a batch say what runs next, and the bar
    ends at 100% with every trial."""
    from armimp_jax.study.runs import console

    clock = [0.0]
    monkeypatch.setattr(console.time, "monotonic", lambda: clock[0])
    stream = io.StringIO()
    per_trial = 30
    bar = console.ProgressBar([(2, 2 * per_trial), (2, 2 * per_trial)], stream=stream)
    bar.begin()
    total = 4 * per_trial
    # (time, substeps done, trials done): 10 s to compile, then 1 s per chunk of 20 substeps
    calls = [(10, 20, 0), (11, 40, 0), (12, 60, 0), (25, 80, 2), (26, 100, 2), (27, 120, 2)]
    lines = []
    for t, done, trials in calls:
        clock[0] = t
        bar(dict(done=done, total=total, trials_done=trials, trials_total=4))
        lines.append(stream.getvalue().rsplit("\r", 1)[-1])
    assert "compiling the first batch (2 trials)" in stream.getvalue()
    assert "ETA after the next chunk" in lines[0]
    assert "ETA 0:04" in lines[1]  # 4 chunks left at 1 s each: the 10 s of compilation left out
    assert "estimating batch 1/2, then compiling the next" in lines[2]
    # the second batch's start took 13 s for a 1 s chunk, and no batch start remains
    assert "ETA 0:02" in lines[3] and "ETA 0:01" in lines[4]
    assert "estimating the last batch" in lines[5]
    clock[0] = 30
    bar.end(4)
    last = stream.getvalue().rstrip("\n").rsplit("\r", 1)[-1]
    assert "100.0%" in last and "trials saved 4/4" in last and "done" in last
    # simulated to the end while the last batch is estimated: saved trials say so
    assert "100.0% simulated" in lines[5] and "trials saved 2/4" in lines[5]
