"""What the solvers share (``armimp_jax._solver.common``: the small-angle rotation) and
``Numerics``, which holds a solver (``armimp_jax._solver.numerics``)."""

import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import armimp_jax as aj
from armimp_jax import paper
from armimp_jax._model.plant import Trig
from armimp_jax._solver.common import rotate

SOLVERS = [
    aj.solvers.RK4(),
    aj.solvers.RK4(kernel="reference"),
    aj.solvers.RK4(kernel="grad"),
    aj.solvers.ARK3(),
    aj.solvers.ARK4(kernel="reference"),
]


def test_rotation_is_exact_to_round_off():
    q = jnp.array([-0.6, -2.2, 1.3])
    t = Trig(jnp.cos(q), jnp.sin(q), jnp.cos(-q), jnp.sin(-q))
    for d in (0.0, 1e-9, 1e-6, 1e-4, 0.02):
        r = rotate(t, jnp.full(3, d), jnp.full(3, -d))
        np.testing.assert_allclose(r.c1, np.cos(q + d), rtol=0, atol=3e-16)
        np.testing.assert_allclose(r.s1, np.sin(q + d), rtol=0, atol=3e-16)
        np.testing.assert_allclose(r.c2, np.cos(-q - d), rtol=0, atol=3e-16)
        np.testing.assert_allclose(r.s2, np.sin(-q - d), rtol=0, atol=3e-16)
    same = rotate(t, jnp.zeros(3), jnp.zeros(3))  # rest stays bitwise at rest
    assert all(np.array_equal(a, b) for a, b in zip(same, t))


def test_rotation_derivative_is_that_of_cos_and_sin():
    """The custom JVP of the truncated series is the exact derivative of ``cos``/``sin``."""
    t = Trig(*(jnp.array(v) for v in (np.cos(0.4), np.sin(0.4), np.cos(-1.1), np.sin(-1.1))))
    d = 3e-3
    jac = jax.jacfwd(lambda d: jnp.stack(rotate(t, d, -2 * d)))(d)
    expected = [-np.sin(0.4 + d), np.cos(0.4 + d), 2 * np.sin(-1.1 - 2 * d), -2 * np.cos(-1.1 - 2 * d)]
    np.testing.assert_allclose(jac, expected, rtol=0, atol=1e-15)


@pytest.mark.parametrize("solver", SOLVERS, ids=repr)
def test_solvers_are_static_hashable_values(solver):
    """No leaves (they fix the program), equal and hashed by value, one key of jit's cache."""
    assert jax.tree.leaves(solver) == [] and jax.tree.leaves(aj.Numerics(solver=solver)) == []
    again = type(solver)(kernel=solver.kernel)
    assert again == solver and hash(again) == hash(solver)
    assert all(other != solver for other in SOLVERS if other is not solver)
    with pytest.raises(dataclasses.FrozenInstanceError):
        solver.kernel = "fast"
    num = aj.Numerics(solver=solver, substeps=3, checkpoint="substep")
    assert num == aj.Numerics(solver=again, substeps=3, checkpoint="substep")
    assert (num.method, num.kernel) == (solver.method, solver.kernel)


def test_defaults_the_paper_and_the_sweep_setting():
    """``Numerics()`` is the converged stiff step; each solver has its own default substeps,
    resolved at construction (an int: equal settings hash equal however they were spelled)."""
    default = aj.Numerics()
    assert default == aj.Numerics(solver=aj.solvers.GradedARK4(kernel="fast"), substeps=4, checkpoint="period")
    assert (
        hash(default) == hash(aj.Numerics(solver=aj.solvers.GradedARK4(), substeps=4)) and type(default.substeps) is int
    )
    expected = {
        aj.solvers.RK4(): 100,
        aj.solvers.RK4(kernel="grad"): 100,
        aj.solvers.ARK3(): 20,
        aj.solvers.ARK4(): 10,
        aj.solvers.GradedARK4(): 4,
    }
    assert {solver: aj.Numerics(solver=solver).substeps for solver in expected} == expected
    assert aj.solvers.PAPER_NUMERICS == aj.Numerics(
        solver=aj.solvers.RK4(kernel="fast"), substeps=100, checkpoint="period"
    )
    assert aj.solvers.SWEEP_NUMERICS == aj.Numerics(solver=aj.solvers.ARK3(kernel="fast"), substeps=20)
    assert dataclasses.replace(aj.solvers.SWEEP_NUMERICS, substeps=80).solver == aj.solvers.ARK3()
    assert dataclasses.replace(default, substeps=16) == aj.Numerics(solver=aj.solvers.GradedARK4(), substeps=16)


@pytest.mark.parametrize("controller", ["pd", "imbic"])
def test_the_default_is_stable_where_the_papers_rk4_diverges(controller):
    """Coulomb torques of 1e-4 and 1e-3 N m (stiction 1.5x), 0.3 s: the paper's RK4 at 100
    substeps diverges, ``Numerics()`` does not (its convergence: docs/performance.md)."""
    base = paper.trial(controller, 0, 1)
    trials = aj.batch.stack_trials(
        [aj.make_trial(base.controller, arm=base.arm, friction=aj.LuGre(tau, 1.5 * tau)) for tau in (1e-4, 1e-3)]
    )
    fd = aj.perturbation(jax.random.PRNGKey(7), 300, paper.perturbation_peak(1))
    run = jax.jit(jax.vmap(aj.simulate, in_axes=(0, None)), static_argnames="numerics")
    assert np.all(run(trials, fd, numerics=aj.solvers.PAPER_NUMERICS).diverged)
    sim = run(trials, fd, numerics=aj.Numerics())
    assert not np.any(sim.diverged) and np.all(np.isfinite(sim.fh)) and np.all(np.ptp(sim.x, axis=1) > 1e-6)


@pytest.mark.parametrize(
    "options, message",
    [
        (dict(method="ark3", kernel="fast"), r"write Numerics\(solver=ARK3\(kernel='fast'\)\)"),
        (dict(kernel="grad"), r"write Numerics\(solver=RK4\(kernel='grad'\)\)"),
        (dict(method="euler"), r"write Numerics\(solver=RK4\(\), ARK3\(\), ARK4\(\) or GradedARK4\(\)\)"),
        (
            dict(solver=aj.solvers.ARK3(), substep=4),
            "unexpected option.* substep; it takes solver, substeps, checkpoint",
        ),
    ],
)
def test_a_solver_named_by_a_string_is_refused_with_the_object_to_pass(options, message):
    with pytest.raises(TypeError, match=message):
        aj.Numerics(**options)


def test_saved_settings_keep_their_keys_and_order():
    """Run settings record ``settings()``; saved result folders hold these keys in this
    order (substeps, kernel, checkpoint, method), and resume only if the JSON text is the same."""
    saved = '{"substeps": 20, "kernel": "grad", "checkpoint": "substep", "method": "rk4"}'
    num = aj.Numerics(solver=aj.solvers.RK4(kernel="grad"), substeps=20, checkpoint="substep")
    assert json.dumps(num.settings()) == saved
    assert aj.solvers.SWEEP_NUMERICS.settings() == dict(substeps=20, kernel="fast", checkpoint="period", method="ark3")


def test_jit_compiles_once_per_numerics_value():
    """Equal numerics built apart share one compiled program; a different solver does not."""
    fd = jnp.zeros((3, 2))
    trial = paper.trial("pd", 1, 1)
    traces = []

    @jax.jit
    def run(t, num):
        traces.append(num)
        return aj.simulate(t, fd, numerics=num).x

    for num in (aj.Numerics(solver=aj.solvers.ARK3(), substeps=2), aj.Numerics(solver=aj.solvers.ARK3(), substeps=2)):
        run(trial, num)
    run(trial, aj.Numerics(solver=aj.solvers.ARK4(), substeps=2))
    assert len(traces) == 2


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (
            dict(solver="ark3"),
            r"Numerics: solver must be RK4\(...\), ARK3\(...\), ARK4\(...\) or GradedARK4\(...\), got 'ark3'",
        ),
        (
            dict(solver=aj.solvers.ARK3),
            r"Numerics: solver must be RK4\(...\), ARK3\(...\), ARK4\(...\) or GradedARK4\(...\), got <class",
        ),
        (dict(checkpoint="step"), "unknown checkpoint 'step'; allowed: 'period', 'substep'"),
        (dict(substeps=0), "substeps .* must be >= 1, got 0"),
    ],
)
def test_bad_numerics_are_refused_with_the_allowed_choices(kwargs, message):
    with pytest.raises(ValueError, match=message):
        aj.Numerics(**kwargs)
