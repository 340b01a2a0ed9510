"""The device check (``sweeps/device_check.sh``): four short measurements on whatever device
JAX runs on (a GPU when one is lent; ``JAX_PLATFORMS=cpu`` forces the host), written as JSON.

- ``simulate``: ``simulate_batch`` of 24 IMBIC trials (5 s, the four arms and friction 0.5-1.1 N m
  cycled, the paper's RK4 at 100 substeps): M substeps/s;
- ``crlb``: the Cramér-Rao bound of one noisy IMBIC trial under a 20 s perturbation;
- ``identify``: one 10 s noisy recording identified from the truth (the arm's 12 entries);
- ``design_gradient``: the value and gradient of the design's criterion on the bound with the
  controller's gains (two arms, 10 s records), compiled once.

Each gives its first call (compilation included) and the median of ``repeats`` calls after it,
``block_until_ready``. A measurement that fails is recorded with its one-line error, so the
check always writes its file (a lent device's time is not spent twice).
"""

from __future__ import annotations

import json
import os
import platform
import statistics
import time

import jax
import numpy as np

import armimp_jax as aj
from armimp_jax import paper

ARM = ("arm.mass", "arm.damping", "arm.stiffness")
NOISE = dict(sensors=aj.Sensors(force_noise=0.05, encoder_counts=2**18), voluntary=aj.VoluntaryForce(0.3, 2.0))


def _timed(call, repeats: int) -> dict:
    t0 = time.perf_counter()
    jax.block_until_ready(call())
    first = time.perf_counter() - t0
    runs = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(call())
        runs.append(time.perf_counter() - t0)
    return dict(first_s=first, run_s=statistics.median(runs), runs_s=runs)


def _trial(location: int = 2, tau_c: float = 1.0):
    return aj.make_trial(aj.IMBIC(), arm=paper.arm(location), friction=aj.LuGre(tau_c, 1.5 * tau_c), **NOISE)


def simulate(repeats: int) -> dict:
    batch, seconds, substeps = 24, 5.0, 100
    n = int(seconds * 1000)
    trials = aj.batch.stack_trials(
        [
            aj.make_trial(
                aj.IMBIC(), arm=paper.arm(1 + i % 4), friction=aj.LuGre(0.5 + 0.1 * (i % 7), 0.8 + 0.1 * (i % 7))
            )
            for i in range(batch)
        ]
    )
    f = np.stack([np.asarray(aj.perturbation(jax.random.key(i), n, 2.25)) for i in range(batch)])
    numerics = aj.Numerics(solver=aj.solvers.RK4(), substeps=substeps)
    out = _timed(lambda: aj.simulate_batch(trials, f, numerics=numerics).x, repeats)
    return out | dict(trials=batch, record_s=seconds, msubsteps_per_s=batch * n * substeps / out["run_s"] / 1e6)


def crlb(repeats: int) -> dict:
    trial = _trial()
    f = np.asarray(aj.perturbation(jax.random.key(2024), 20_000, 2.25))
    bound = aj.crlb(trial, f, free=ARM)
    out = _timed(lambda: aj.crlb(trial, f, free=ARM).covariance, repeats)
    return out | dict(record_s=20.0, near_linear=bool(bound.near_linear), minutes=float(bound.record_for(0.1) / 60))


def identify(repeats: int) -> dict:
    trial = _trial()
    f = np.asarray(aj.perturbation(jax.random.key(2024), 10_000, 10.0))
    rec = aj.simulate(trial, f, key=jax.random.key(3), numerics=aj.solvers.IDENTIFY_NUMERICS)
    results = []

    def call():
        results.append(aj.identify(trial, f, rec.x, rec.fh, free=ARM, draws=16, key=jax.random.key(0)))
        return results[-1].cost

    out = _timed(call, repeats)
    return out | dict(record_s=10.0, converged=bool(results[-1].converged), iterations=int(results[-1].iterations))


def design_gradient(repeats: int) -> dict:
    """The value and gradient of the design's criterion on the bound (two arms, 10 s, the
    spectrum of an 8-line multisine and the controller's four gains): one compiled program,
    what each step of ``aj.design(..., method=aj.experiment.CramerRao(controller=True))`` evaluates."""
    import jax.numpy as jnp

    from armimp_jax._design import bound_design, controller_design
    from armimp_jax._design.criterion import default_targets
    from armimp_jax._identification import layout as lay

    trials = [_trial(loc, 0.0) for loc in (1, 2)]
    family = aj.signals.multisine(np.geomspace(0.1, 15.0, 8), 1.0)
    limits = aj.experiment.Limits(0.66, 2.25, 10.0, peak_displacement=0.01)
    layout = lay.make_layout(ARM)
    idx = np.asarray(default_targets(layout))
    key = jax.random.key(0)

    def criterion(z, offsets):
        args = (family, trials, layout, idx, limits, "worst", key, 10_000, 1e-3, True)
        return bound_design._objective(z, offsets, *args)

    value_and_grad = jax.jit(jax.value_and_grad(criterion, has_aux=True))
    z = {"shape": np.zeros((2, 8)), "gains": controller_design.initial_log_gains(trials[0])}
    offsets = jnp.zeros((2, idx.size))
    out = _timed(lambda: value_and_grad(z, offsets)[1]["shape"], repeats)
    return out | dict(arms=2, record_s=10.0, parameters=16 + 4)


CHECKS = dict(simulate=simulate, crlb=crlb, identify=identify, design_gradient=design_gradient)


def run(out_path, *, repeats: int = 3, only=None) -> dict:
    """Run the checks (``only``: names of ``CHECKS``; default all) and write their JSON to
    ``out_path``; returns it."""
    device = jax.devices()[0]
    doc = dict(
        platform=device.platform,
        device=str(getattr(device, "device_kind", device)),
        devices=jax.device_count(),
        jax=jax.__version__,
        armimp_jax=aj.__version__,
        host=platform.node(),
        cpus=os.cpu_count(),
        repeats=repeats,
        checks={},
    )
    for name in only or CHECKS:
        t0 = time.perf_counter()
        try:
            doc["checks"][name] = CHECKS[name](repeats)
        except Exception as err:  # recorded, never lost: the file is written whatever fails
            doc["checks"][name] = dict(error=" ".join(f"{type(err).__name__}: {err}".split())[:300])
        doc["checks"][name]["wall_s"] = time.perf_counter() - t0
        print(json.dumps({name: doc["checks"][name]}), flush=True)
    with open(out_path, "w") as fh:
        json.dump(doc, fh, indent=1)
    return doc
