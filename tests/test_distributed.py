"""armimp_jax.study.runs.distributed: the command-line options (one-line refusals before JAX starts), and a
two-process ``jax.distributed`` job on one machine (one CPU device each, Gloo collectives)
that gives the single-process results bit for bit."""

import argparse
import importlib.util
import json
import os
import pathlib
import socket
import subprocess
import sys

import numpy as np
import pytest

from armimp_jax.study.runs import distributed
from armimp_jax.study.runs import results as res

ROOT = pathlib.Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "sweeps" / "reproduce_paper.py"
# A tiny reproduction: 4 conditions x 2 seeds, 2.2 s records.
TINY = [
    *("--seconds", "2.2", "--substeps", "4", "--nperseg", "512", "--noverlap", "384", "--no-ablation"),
    *("--locations", "1", "--frictions", "0", "2", "--perturbations", "1", "--seeds", "2", "--batch-size", "8"),
]


def run_script(*args, env=None, timeout=300):
    return subprocess.run(
        [sys.executable, str(SCRIPT), *args], capture_output=True, text=True, cwd=ROOT, timeout=timeout, env=env
    )


def one_line_error(proc, *fragments):
    assert proc.returncode == 2, proc.stdout + proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("reproduce_paper: error: "), proc.stderr
    for f in fragments:
        assert f in lines[0], (f, lines[0])


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def cpu_env(devices: int) -> dict:
    """The environment of a process that sees ``devices`` CPU devices."""
    env = dict(os.environ)
    env["XLA_FLAGS"] = f"{env.get('XLA_FLAGS', '')} --xla_force_host_platform_device_count={devices}".strip()
    env["JAX_PLATFORMS"] = "cpu"
    return env


def launch(script, args_of_process) -> list:
    """One process per entry of ``args_of_process`` (each with one CPU device) joined by a
    coordinator on a free local port; returns the ``Popen``s."""
    common = ["--coordinator", f"127.0.0.1:{free_port()}", "--num-processes", str(len(args_of_process))]
    return [
        subprocess.Popen(
            [sys.executable, str(script), *args, *common, "--process-id", str(i)],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            cwd=ROOT,
            env=cpu_env(1),
        )
        for i, args in enumerate(args_of_process)
    ]


def parser():
    ap = argparse.ArgumentParser()
    distributed.add_arguments(ap)
    return ap


def test_options_parse_and_a_single_process_needs_none():
    args = parser().parse_args(
        ["--coordinator", "10.0.0.1:1234", "--num-processes", "4", "--process-id", "3", "--compilation-cache", "c"]
    )
    assert (args.coordinator, args.num_processes, args.process_id, args.auto_cluster) == ("10.0.0.1:1234", 4, 3, False)
    assert args.compilation_cache == pathlib.Path("c")
    distributed.check_arguments(args)
    plain = parser().parse_args([])
    distributed.check_arguments(plain)
    assert plain.compilation_cache is None and not plain.auto_cluster
    auto = parser().parse_args(["--auto-cluster", "--num-processes", "2"])  # the rest from the cluster
    distributed.check_arguments(auto)
    # in a single process: not distributed, and it writes
    assert not distributed.is_distributed() and distributed.is_writer()
    tree = dict(a=np.arange(3))
    assert distributed.broadcast_from_writer(tree) is tree


@pytest.mark.parametrize(
    "args, message",
    [
        (["--coordinator", "127.0.0.1:1234"], "--coordinator needs --num-processes and --process-id as well"),
        (["--num-processes", "2", "--process-id", "0"], "--num-processes and --process-id need --coordinator"),
        (["--coordinator", "nohost", "--num-processes", "2", "--process-id", "0"], "must be HOST:PORT"),
        (["--coordinator", "h:70000", "--num-processes", "2", "--process-id", "0"], "port in 1-65535, got 'h:70000'"),
        (["--coordinator", "h:1", "--num-processes", "0", "--process-id", "0"], "--num-processes must be >= 1, got 0"),
        (["--coordinator", "h:1", "--num-processes", "2", "--process-id", "2"], "below --num-processes (2), got 2"),
        (["--coordinator", "h:1", "--num-processes", "2", "--process-id", "-1"], "--process-id must be >= 0"),
        (["--num-processes", "two"], "argument --num-processes: invalid int value: 'two'"),
        (["--compilation-cache", str(SCRIPT)], "--compilation-cache"),
        (["--replot", str(ROOT), "--auto-cluster"], "--replot runs in one process"),
    ],
)
def test_bad_distributed_options_fail_in_one_line_before_jax_starts(args, message):
    proc = run_script("--quick", *args) if "--replot" not in args else run_script(*args)
    one_line_error(proc, message)
    assert "conditions x" not in proc.stdout


def _trials(out):
    records = {}
    for path in sorted((out / "trials").glob("*.npz")):
        rec = res.load_record(path)
        records[path.stem] = rec
    return records


@pytest.mark.slow
def test_two_processes_give_the_single_process_results_bit_for_bit(tmp_path):
    # One process with two CPU devices against two processes with one each: the same mesh
    # size and per-device batches, so the same compiled programs and the same numbers.
    single, multi, other = tmp_path / "single", tmp_path / "multi", tmp_path / "not-written"
    ref = run_script(*TINY, "--out", str(single), env=cpu_env(2))
    assert ref.returncode == 0, ref.stdout + ref.stderr
    procs = launch(SCRIPT, [[*TINY, "--out", str(out)] for out in (multi, other)])
    outputs = [p.communicate(timeout=300) for p in procs]
    for p, (stdout, stderr) in zip(procs, outputs):
        assert p.returncode == 0, stdout + stderr
    assert "done in" in outputs[0][0] and "process 1: computed its shards of 8 trial(s)" in outputs[1][0]
    assert not other.exists()  # only process 0 writes
    a, b = _trials(single), _trials(multi)
    assert sorted(a) == sorted(b) and len(a) == 8
    for tid in a:
        for name, arr in a[tid].arrays.items():
            np.testing.assert_array_equal(b[tid].arrays[name], arr, err_msg=f"{tid}: {name}")
        wall = ("batch_wall_s",)
        assert {k: v for k, v in a[tid].meta.items() if k not in wall} == {
            k: v for k, v in b[tid].meta.items() if k not in wall
        }
    ra, rb = (json.loads((d / "results.json").read_text()) for d in (single, multi))
    assert ra["conditions"] == rb["conditions"] and ra["claims"] == rb["claims"]
    assert rb["versions"]["devices"] == 2 and ra["key"] == rb["key"]


@pytest.mark.slow
def test_processes_with_other_settings_are_refused_in_every_process(tmp_path):
    procs = launch(SCRIPT, [[*TINY, "--out", str(tmp_path), *extra] for extra in ([], ["--mhat", "0.5"])])
    for p in procs:
        _, stderr = p.communicate(timeout=300)
        assert p.returncode == 2 and "process(es) 1 have other run settings than process 0" in stderr, stderr


def test_the_script_parses_the_distributed_options():
    spec = importlib.util.spec_from_file_location("reproduce_paper", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    args = module.parse(["--auto-cluster", "--compilation-cache", "/tmp/cache"])
    assert args.auto_cluster and args.compilation_cache == pathlib.Path("/tmp/cache")


SWEEP = ROOT / "sweeps" / "sweep.py"
TINY_SWEEP = [
    *("--set", "controller=pd,imbic", "--set", "tau_c=0,0.5", "--seeds", "2", "--seconds", "2.2"),
    *("--nperseg", "512", "--substeps", "4", "--batch-size", "8"),
]


@pytest.mark.slow
def test_a_two_process_sweep_gives_the_single_process_table(tmp_path):
    single, multi, other = tmp_path / "single", tmp_path / "multi", tmp_path / "not-written"
    ref = subprocess.run(
        [sys.executable, str(SWEEP), *TINY_SWEEP, "--out", str(single)],
        capture_output=True,
        text=True,
        cwd=ROOT,
        env=cpu_env(2),
        timeout=300,
    )
    assert ref.returncode == 0, ref.stdout + ref.stderr
    procs = launch(SWEEP, [[*TINY_SWEEP, "--out", str(out)] for out in (multi, other)])
    for p in procs:
        stdout, stderr = p.communicate(timeout=300)
        assert p.returncode == 0, stdout + stderr
    assert not other.exists()  # only process 0 writes
    assert (multi / "trials.csv").read_text() == (single / "trials.csv").read_text()


def test_the_sweep_script_refuses_bad_distributed_options_in_one_line():
    proc = subprocess.run(
        [sys.executable, str(SWEEP), "--set", "tau_c=0", "--out", "x", "--coordinator", "127.0.0.1:1234"],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=60,
    )
    assert proc.returncode == 2 and proc.stderr.strip().splitlines() == [
        "sweep: error: --coordinator needs --num-processes and --process-id as well (or --auto-cluster)"
    ], proc.stderr
