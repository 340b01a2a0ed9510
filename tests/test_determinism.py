"""Determinism across compilations and processes: the same inputs give the same bits in a new
process that compiles every program afresh (no compilation cache), for the perturbation, a noisy
simulation with RK4's fast kernel (sensor noise, encoder steps, the person's force: every key
stream), one through LuGre friction with ``Numerics()``'s ``GradedARK4``, and the estimator on
them (docs/design.md, "Determinism")."""

import json
import os
import pathlib
import subprocess
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]

# Run here (programs from this worker, or from the suite's compilation cache) and in a new
# process without a cache (every program compiled again): their digests must agree.
CODE = """
import hashlib

import jax
import numpy as np

import armimp_jax as aj
from armimp_jax import presets


def digests():
    def digest(a):
        return hashlib.sha256(np.ascontiguousarray(np.asarray(a)).tobytes()).hexdigest()

    noise = dict(sensors=aj.Sensors(force_noise=0.05, encoder_counts=2**18), voluntary=aj.VoluntaryForce(0.3, 2.0))
    f = aj.perturbation(jax.random.PRNGKey(7), 2000, 2.25)
    run = jax.jit(aj.simulate, static_argnames="numerics")
    out = {"perturbation": digest(f)}
    cases = {
        "imbic-rk4": (aj.make_trial(aj.IMBIC(), arm=presets.arm(2), friction=aj.NO_FRICTION, **noise),
                      aj.Numerics(solver=aj.solvers.RK4(), substeps=5)),
        "pd-lugre-graded": (aj.make_trial(aj.PD(), arm=presets.arm(2), friction=aj.LuGre(0.3, 0.45), **noise),
                            aj.Numerics()),
    }
    for name, (trial, numerics) in cases.items():
        sim = run(trial, f, key=jax.random.PRNGKey(11), numerics=numerics)
        est = aj.estimate(f, sim.x, sim.fh, nperseg=512, noverlap=384)
        for field in ("x", "fh", "fu"):
            out[f"{name}.{field}"] = digest(getattr(sim, field))
        out[f"{name}.Z"] = digest(est.Z)
    return out
"""


def test_a_new_process_compiling_afresh_gives_the_same_bits():
    scope: dict = {}
    exec(compile(CODE, "determinism", "exec"), scope)
    here = scope["digests"]()
    child = CODE + "\nimport json\njax.config.update('jax_enable_x64', True)\nprint(json.dumps(digests()))\n"
    env = dict(os.environ, ARMIMP_JAX_CACHE_DIR="off", JAX_ENABLE_COMPILATION_CACHE="false")
    proc = subprocess.run([sys.executable, "-c", child], capture_output=True, text=True, cwd=ROOT, env=env, timeout=600)
    assert proc.returncode == 0, proc.stderr
    there = json.loads(proc.stdout.strip().splitlines()[-1])
    assert there == here, [k for k in here if here[k] != there.get(k)]
