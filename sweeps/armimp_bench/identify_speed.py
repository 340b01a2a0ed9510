"""``identify``'s speed in a lab's three cases (``sweeps/bench_identify_speed.py``, issue 47):

- ``single``: one 20 s PD recording through LuGre 0.8 / 1.2 N m (10 N peak), the arm and both
  Coulomb torques free from a generic start (a generic arm, half the torque); target 30 s warm;
- ``pooled``: eight recordings of 20 s (the paper's four postures, two trials at each, every
  recording its own perturbation), one arm per posture and the torques shared, from the same
  generic start; target 3 min warm;
- ``checked``: the new user's lab for 20 s (admittance through ``CoulombViscous(0.05)``, a non-paper
  arm at location 1's posture, the arm free from a generic start): the self-check runs; target
  1.5 times 2.4.0's; ``linear``: PD without friction at paper arm 2, 20 s, the same start: the
  loop is linear, nothing is checked; target no slower than 2.4.0. Each three warm calls
  (``REPEATS``), their median reported;
- ``reaches``: ``identify`` over an ensemble of 40 reaches of the movement's base case (PD, no
  friction: the intervals' check runs), and ``reaches-lugre`` (IMBIC through LuGre 0.5 / 0.75 N m,
  ``tau_c`` free); each in a fresh process with one CPU device, then with one per core (the
  route's simulations split over them), two calls each; target 2 min warm through friction;
- ``script``: a 48 s IMBIC recording at 1 N m (LuGre 1 / 1.5 N m, the paper's level-1
  perturbation, arm 2) through ``estimate_recording.py --model`` as a lab runs it, twice (the
  second loads the compiled programs from the cache); target 60 s on the second run.

Each in-process case calls ``identify`` twice and reports both times (the first compiles).
Every time is a wall time on this host; the truth's noise is the studies' (``coverage.noise``).
"""

from __future__ import annotations

import json
import os
import pathlib
import subprocess
import sys
import time

import jax
import numpy as np

import armimp_jax as aj
from armimp_jax import presets
from armimp_jax.study.runs.results import atomic_write_json
from armimp_jax.study.sweep import coverage as cov

FREE = (*cov.ARM, "friction.tau_c")
TARGETS_S = dict(single=30.0, pooled=180.0, script=60.0, checked=None, linear=None, reaches=None)
TARGETS_S["reaches-lugre"] = 120.0
REPEATS = 3  # warm calls of the checked and linear cases
# the new user's lab's subject (armimp_bench.matrix's OTHER_ARM): heavier along x, with off-diagonal terms
LAB_ARM = dict(
    mass=[[1.6, 0.25], [0.2, 1.1]], damping=[[14.0, 3.0], [2.5, 10.0]], stiffness=[[260.0, 60.0], [45.0, 180.0]]
)
ROOT = pathlib.Path(__file__).resolve().parents[2]


def _generic(endpoint) -> aj.Arm:
    return aj.Arm(np.eye(2), 5.0 * np.eye(2), 150.0 * np.eye(2), endpoint)


def _trial(controller, arm, friction):
    return aj.make_trial(controller, arm=arm, friction=friction, **cov.noise())


def _timed(call) -> dict:
    """Two calls of ``call`` (the first compiles): their wall times and the second's answer."""
    times, res = [], None
    for _ in range(2):
        t0 = time.perf_counter()
        res = call()
        times.append(time.perf_counter() - t0)
    return dict(
        first_s=times[0],
        second_s=times[1],
        converged=bool(res.converged),
        message=res.message,
        iterations=int(res.iterations),
        forward_s=float(res.forward_s),
        warnings=list(res.warnings),
    )


def single(seconds: float = 20.0, draws: int = 64) -> dict:
    """The ``single`` case (module docstring)."""
    truth = _trial(aj.PD(), presets.arm(2), aj.LuGre(0.8, 1.2))
    start = _trial(aj.PD(), _generic(presets.location_endpoint(2)), aj.LuGre(0.4, 1.2))
    f = aj.perturbation(jax.random.key(2024), int(round(seconds * 1000)), 10.0)
    rec = cov.record(truth, f, 3)
    out = _timed(lambda: aj.identify(start, f, rec.x, rec.fh, free=FREE, draws=draws))
    return out | dict(recordings=1, seconds=seconds, draws=draws)


def pooled(seconds: float = 20.0, trials: int = 2, draws: int = 64) -> dict:
    """The ``pooled`` case (module docstring): ``trials`` recordings at each paper posture."""
    recordings = []
    for loc in presets.LOCATIONS:
        truth = _trial(aj.PD(), presets.arm(loc), aj.LuGre(0.8, 1.2))
        start = _trial(aj.PD(), _generic(presets.location_endpoint(loc)), aj.LuGre(0.4, 1.2))
        for t in range(trials):
            f = aj.perturbation(jax.random.key(100 * loc + t), int(round(seconds * 1000)), 10.0)
            rec = cov.record(truth, f, 10 * loc + t)
            recordings.append(aj.Recording(start, f, rec.x, rec.fh, group=f"posture {loc}"))
    out = _timed(lambda: aj.identify(recordings, free=FREE, draws=draws))
    return out | dict(recordings=len(recordings), seconds=seconds, draws=draws)


def _repeated(controller, arm, friction, seconds: float, draws: int) -> dict:
    """A first call (compiling) then ``REPEATS`` warm calls of ``identify`` on one recording of
    ``arm`` from a generic start: their times and the warm median."""
    truth = _trial(controller, arm, friction)
    start = _trial(controller, _generic(arm.endpoint), friction)
    f = aj.perturbation(jax.random.key(2024), int(round(seconds * 1000)), presets.perturbation_peak(1))
    rec = cov.record(truth, f, 3)
    times = []
    for _ in range(1 + REPEATS):
        t0 = time.perf_counter()
        res = aj.identify(start, f, rec.x, rec.fh, free=cov.ARM, draws=draws)
        times.append(time.perf_counter() - t0)
    return dict(
        first_s=times[0],
        warm_s=times[1:],
        second_s=float(np.median(times[1:])),
        converged=bool(res.converged),
        iterations=int(res.iterations),
        seconds=seconds,
        draws=draws,
        version=aj.__version__,
    )


def checked(seconds: float = 20.0, draws: int = 64) -> dict:
    """The ``checked`` case (module docstring)."""
    arm = aj.Arm(**LAB_ARM, endpoint=presets.location_endpoint(1))
    return _repeated(aj.Admittance(), arm, aj.CoulombViscous(0.05), seconds, draws)


def linear(seconds: float = 20.0, draws: int = 64) -> dict:
    """The ``linear`` case (module docstring)."""
    return _repeated(aj.PD(), presets.arm(2), aj.NO_FRICTION, seconds, draws)


def _write_lab_files(folder: pathlib.Path, seconds: float) -> tuple[pathlib.Path, pathlib.Path]:
    """The ``script`` case's recording (NPZ) and model config (TOML) in ``folder``."""
    arm = presets.arm(2)
    truth = _trial(aj.IMBIC(), arm, aj.LuGre(1.0, 1.5))
    f = aj.perturbation(jax.random.key(48), int(round(seconds * 1000)), presets.perturbation_peak(1))
    rec = cov.record(truth, f, 7)
    data = folder / "imbic48.npz"
    np.savez(data, f_delta=np.asarray(f), x=np.asarray(rec.x), fh=np.asarray(rec.fh))
    config = {
        "controller": {"type": "imbic"},
        "sensors": {"force_noise": 0.05, "encoder_counts": 2**18},
        "voluntary": {"std": 0.3, "cutoff": 2.0},
        "arm": {
            "mass": np.eye(2).tolist(),
            "damping": (5.0 * np.eye(2)).tolist(),
            "stiffness": (150.0 * np.eye(2)).tolist(),
            "endpoint": np.asarray(arm.endpoint).tolist(),
        },
        "friction": {"tau_c": 0.5, "tau_s": 1.5},
        "identify": {"free": list(FREE)},
    }
    lines = [f"[{s}]\n" + "".join(f"{k} = {json.dumps(v)}\n" for k, v in t.items()) for s, t in config.items()]
    model = folder / "imbic48.toml"
    model.write_text("\n".join(lines))
    return data, model


def script(folder, seconds: float = 48.0) -> dict:
    """The ``script`` case (module docstring): ``estimate_recording.py --model`` run twice in
    fresh processes (the compiled programs' cache as the user's environment sets it)."""
    folder = pathlib.Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    data, model = _write_lab_files(folder, seconds)
    runs = []
    for i in range(2):
        out = folder / f"run{i + 1}"
        cmd = [sys.executable, str(ROOT / "sweeps" / "estimate_recording.py"), str(data), "--fs", "1000"]
        t0 = time.perf_counter()
        done = subprocess.run([*cmd, "--model", str(model), "--out", str(out)], capture_output=True, text=True)
        wall = time.perf_counter() - t0
        if done.returncode != 0:
            raise RuntimeError(f"estimate_recording.py failed ({done.returncode}): {done.stderr.strip()[-400:]}")
        doc = json.loads((out / "identification.json").read_text())
        runs.append(dict(wall_s=wall, identify_s=doc["time_s"], converged=doc["converged"]))
    return dict(first_s=runs[0]["wall_s"], second_s=runs[1]["wall_s"], runs=runs, seconds=seconds)


def ensemble_calls(case: str) -> dict:
    """Two calls of ``identify`` over 40 reaches of the movement's ``case`` (``armimp_bench.
    movement_model``) in this process: their wall times, the devices, the answer's convergence."""
    from armimp_bench import movement_model as mm

    truth, model, free = mm.case_trials(case)
    ens = aj.simulate_ensemble(truth, mm.perturbation(case), key=jax.random.key(5), repetitions=40, samples=1600)
    times, res = [], None
    for _ in range(2):
        t0 = time.perf_counter()
        res = aj.identify(model, ens, free=free)
        times.append(time.perf_counter() - t0)
    return dict(
        first_s=times[0], second_s=times[1], devices=len(jax.devices()), converged=bool(res.converged), steps=res.steps
    )


def reaches(case: str) -> dict:
    """The ``reaches`` cases (module docstring): ``ensemble_calls`` in a fresh process with one CPU
    device, then with one per core; the warm ratio of the two."""
    runs = {}
    for devices in sorted({1, os.cpu_count() or 1}):
        env = dict(os.environ, ARMIMP_JAX_CPU_DEVICES=str(devices), PYTHONPATH=str(ROOT / "sweeps"))
        code = f"from armimp_bench import identify_speed as s; s.child({case!r})"
        done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
        if done.returncode != 0:
            raise RuntimeError(f"identify over an ensemble failed ({done.returncode}): {done.stderr.strip()[-400:]}")
        runs[devices] = json.loads(done.stdout.strip().splitlines()[-1])
        if runs[devices]["devices"] != devices:  # XLA_FLAGS' own device count wins over the variable
            raise RuntimeError(f"asked for {devices} CPU devices, the process had {runs[devices]['devices']}")
    one, most = runs[1], runs[max(runs)]
    return dict(
        most,
        runs={str(d): r for d, r in runs.items()},
        one_device_s=one["second_s"],
        speedup=one["second_s"] / most["second_s"],
        case=case,
        repetitions=40,
        version=aj.__version__,
    )


def child(case: str) -> None:
    """``ensemble_calls`` in a process the ``reaches`` case starts: JAX set up, one JSON line out."""
    from armimp_jax.runtime import configure

    configure(compilation_cache=False)  # each process compiles afresh: its first call is a user's first
    print(json.dumps(ensemble_calls(case)))


def run(cases, out) -> dict:
    """Each of ``cases`` (``single``, ``pooled``, ``script``); JSON in ``out`` (the script's files
    beside it)."""
    out = pathlib.Path(out)
    measure = dict(
        single=single, pooled=pooled, checked=checked, linear=linear, script=lambda: script(out.parent / "script")
    )
    measure |= {"reaches": lambda: reaches("pd"), "reaches-lugre": lambda: reaches("imbic-lugre")}
    results = {}
    for name in cases:
        results[name] = measure[name]()
        results[name]["target_s"] = TARGETS_S[name]
        atomic_write_json(out, dict(cases=results))
    return results
