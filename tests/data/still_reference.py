"""Writes ``still_reference.npz``: short noisy simulations of a still arm under PD, IMBIC and
admittance with joint friction, through RK4 (fast and reference kernels), ARK3 and GradedARK4,
as the simulator computed them before arms could move (commit d0a3dee). ``test_movement.py``
holds today's ``simulate`` to these bits: a still arm must run the code it always ran.

Run from the repository root: ``python tests/data/still_reference.py [OUT.npz]``, under the
package of commit d0a3dee (``git archive d0a3dee | tar -x -C DIR``, ``PYTHONPATH=DIR``). The file
records the JAX version it was made with; the test is skipped under another.
"""

import pathlib
import sys

import jax
import numpy as np

import armimp_jax as aj
from armimp_jax import presets, runtime

SAMPLES = 300
CONTROLLERS = {"pd": aj.PD, "imbic": aj.IMBIC, "admittance": aj.Admittance}


def numerics():
    """name -> (Numerics, friction): RK4 at the paper's friction level 1, the stiff-friction
    solvers at a direct-drive robot's."""
    paper_friction, small = presets.friction(1), aj.LuGre(tau_c=0.05, tau_s=0.075)
    return {
        "rk4": (aj.Numerics(solver=aj.solvers.RK4(), substeps=20), paper_friction),
        "rk4ref": (aj.Numerics(solver=aj.solvers.RK4(kernel="reference"), substeps=20), paper_friction),
        "ark3": (aj.Numerics(solver=aj.solvers.ARK3(), substeps=10), small),
        "gark4": (aj.Numerics(), small),
    }


def case(controller: str, numerics_name: str):
    """The trial, perturbation, key and numerics of one reference case."""
    num, friction = numerics()[numerics_name]
    noise = dict(sensors=aj.Sensors(force_noise=0.05, encoder_counts=2**18), voluntary=aj.VoluntaryForce(0.3, 2.0))
    trial = aj.make_trial(CONTROLLERS[controller](), arm=presets.arm(3), friction=friction, **noise)
    f = aj.perturbation(jax.random.PRNGKey(5), SAMPLES, 2.25)
    return trial, f, jax.random.PRNGKey(9), num


def run(controller: str, numerics_name: str):
    trial, f, key, num = case(controller, numerics_name)
    sim = jax.jit(aj.simulate, static_argnames="numerics")(trial, f, key=key, numerics=num)
    return {field: np.asarray(getattr(sim, field)) for field in ("x", "xd", "fh", "fu", "q", "z")}


if __name__ == "__main__":
    # The test suite's own set-up (tests/conftest.py): XLA:CPU's code generation moves results in
    # their last bits, so the reference is made under the flags the test runs with.
    jax.config.update("jax_enable_x64", True)
    jax.config.update("jax_numpy_rank_promotion", "raise")
    runtime.configure(vector_width=256, compilation_cache=False)
    out = {"jax_version": np.asarray(jax.__version__)}
    for c in CONTROLLERS:
        for n in numerics():
            for field, value in run(c, n).items():
                out[f"{c}.{n}.{field}"] = value
    target = sys.argv[1] if len(sys.argv) > 1 else pathlib.Path(__file__).with_name("still_reference.npz")
    np.savez_compressed(target, **out)
