"""The stiff-friction solvers (``ARK3``, ``ARK4``; ``armimp_jax._solver.ark``): stable and
continuous for every Coulomb torque, convergent, equal to RK4 where RK4 works,
differentiable near zero friction, their kernels equal to round-off."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import armimp_jax as aj
from armimp_jax import paper
from armimp_jax._model.plant import PlantState, plant_model
from armimp_jax._solver.ark import from_momentum, to_momentum

TAUS = (0.0, 1e-4, 1e-3, 1e-2, 0.05, 0.2, 1.0, 4.0)  # Coulomb torques [N m], stiction 1.5x


def _fd():
    return aj.perturbation(jax.random.PRNGKey(7), 1500, 2.25)


def _phi(trial, fd, numerics):
    sim = aj.simulate(trial, fd, numerics=numerics)
    est = aj.estimate(fd, sim.x, sim.fh, nperseg=512, noverlap=384)
    return aj.spectra.accuracy(est.Z, est.f, trial.arm)[0], sim.diverged


def _batch(controller, taus, tau_s_ratio=1.5):
    ctrl = paper.trial(controller, 0, 1).controller
    return aj.batch.stack_trials(
        [aj.make_trial(ctrl, arm=paper.arm(1), friction=aj.LuGre(t, tau_s_ratio * t)) for t in taus]
    )


def _phis(trials, numerics):
    fd = _fd()
    phi, diverged = jax.jit(jax.vmap(lambda t: _phi(t, fd, numerics)))(trials)
    return np.asarray(phi), np.asarray(diverged)


@pytest.mark.parametrize("solver, order", [(aj.solvers.ARK3, 3), (aj.solvers.ARK4, 4)])
def test_tableaus_meet_their_order_conditions(solver, order):
    """Both halves of each pair satisfy the Runge-Kutta order conditions (to ``order``), so
    a typo in a coefficient cannot pass."""
    tableau = solver.tableau
    s = len(tableau.c)
    b, c = np.array(tableau.b), np.array(tableau.c)
    for rows, diag in ((tableau.explicit, 0.0), (tableau.implicit, tableau.gamma)):
        a = np.zeros((s, s))
        for i, row in enumerate(rows):
            a[i + 1, : len(row)] = row
            a[i + 1, i + 1] = diag
        np.testing.assert_allclose(a.sum(axis=1), c, atol=1e-15)
        conditions = [b.sum() - 1, b @ c - 1 / 2, b @ c**2 - 1 / 3, b @ a @ c - 1 / 6]
        if order >= 4:
            conditions += [b @ c**3 - 1 / 4, b @ (c * (a @ c)) - 1 / 8, b @ a @ c**2 - 1 / 12, b @ a @ a @ c - 1 / 24]
        np.testing.assert_allclose(conditions, 0.0, atol=1e-15)


def test_momentum_form_round_trips_and_keeps_bristle_free_joints_at_zero():
    trial = paper.trial("pd", 1, 2)
    model = plant_model(trial.q0, trial.x0, trial.arm, aj.LuGre([0.3, 0.0], [0.45, 0.0]), trial.robot)
    s = PlantState(trial.q0[0] + 0.01, trial.q0[1] - 0.02, 0.3, -0.2, 2e-6, 0.0, 1e-4, -2e-4)
    back = from_momentum(to_momentum(s, model), model)
    np.testing.assert_allclose(np.array(back), np.array(s), rtol=1e-14, atol=1e-20)
    fu = jnp.array([3.0, -2.0])
    out = aj.solvers.ARK3().integrate_period(s, fu, model, period=1e-3, substeps=4)
    assert float(out.z2) == 0.0 and float(out.z1) != 2e-6  # joint 2 has no bristles (g = 0)


@pytest.mark.parametrize("controller", ["pd", "imbic"])
def test_every_coulomb_torque_is_stable_and_continuous_at_zero(controller):
    """From 0 to 4 N m at 10 substeps: nothing diverges (classical RK4 diverges at
    1e-4 and 1e-3 N m even at 100 substeps), and phi_T at 1e-4 N m is within 1% of no
    Coulomb friction (docs/model.md section 4: the model's limit is continuous)."""
    phi, diverged = _phis(_batch(controller, TAUS), aj.Numerics(solver=aj.solvers.ARK3(), substeps=10))
    assert not diverged.any() and np.all(np.isfinite(phi)), phi
    assert abs(phi[1] - phi[0]) < 0.01 * phi[0], phi


@pytest.mark.slow  # measured in full by sweeps/bench_convergence.py; fast: stability and agreement with RK4 here
def test_refinement_converges_at_small_and_paper_friction():
    """Errors against 80 substeps shrink as the step does (order reduced from 3 by the
    stick-slip kinks: about 2), for stiff (1e-4, 1e-2 N m) and paper-level (1 N m) friction."""
    taus = (1e-4, 1e-2, 1.0)
    trials = _batch("pd", taus)
    phi = {k: _phis(trials, aj.Numerics(solver=aj.solvers.ARK3(), substeps=k))[0] for k in (5, 20, 80)}
    e5, e20 = (np.max(np.abs(phi[k] - phi[80]) / phi[80]) for k in (5, 20))
    assert e20 < e5 / 4 and e5 < 1e-3, (e5, e20)


def test_agrees_with_rk4_at_the_paper_friction_levels():
    """Where classical RK4 is stable (levels 1 and 2, docs/model.md section 4): phi_T within 1e-6."""
    trials = aj.batch.stack_trials([paper.trial("imbic", level, 1) for level in (1, 2)])
    ark, _ = _phis(trials, aj.Numerics(solver=aj.solvers.ARK3(), substeps=40))
    rk4, _ = _phis(trials, aj.solvers.PAPER_NUMERICS)
    np.testing.assert_allclose(ark, rk4, rtol=1e-6)


@pytest.mark.slow  # 20 s cold (the suite's budget); test_simulate's gradient tests stay fast
def test_gradients_near_zero_friction_are_finite_and_match_central_differences():
    """d phi_T / d tau_c (stiction 1.5 tau_c): at 1e-3 N m equal to a central difference; at
    exactly 0 (no bristles) finite: there the function has no derivative from the right
    (difference quotients do not settle), and the gradient is that of the bristle-free branch."""
    fd = _fd()
    ctrl = paper.trial("pd", 0, 1).controller
    numerics = aj.Numerics(solver=aj.solvers.ARK3(), substeps=10)

    def phi(tc):
        return _phi(aj.make_trial(ctrl, arm=paper.arm(1), friction=aj.LuGre(tc, 1.5 * tc)), fd, numerics)[0]

    value_and_grad = jax.jit(jax.value_and_grad(phi))  # values and gradients from one program
    assert np.isfinite(float(value_and_grad(0.0)[1]))
    tc, eps = 1e-3, 1e-7
    central = (float(value_and_grad(tc + eps)[0]) - float(value_and_grad(tc - eps)[0])) / (2 * eps)
    np.testing.assert_allclose(float(value_and_grad(tc)[1]), central, rtol=1e-3)


# ARK4 runs the same kernels (ark.py's trig and frame, another tableau, whose order
# conditions are checked above); its fast kernel is also the reference of test_graded.py
@pytest.mark.parametrize("solver", [aj.solvers.ARK3, pytest.param(aj.solvers.ARK4, marks=pytest.mark.slow)])
def test_fast_and_reference_kernels_agree_to_round_off(solver):
    """Rotated and evaluated ``cos/sin`` differ by round-off only, over 1.5 s at the paper's
    friction levels (bound as RK4's, ``test_rk4.py``)."""
    fd = _fd()
    trials = aj.batch.stack_trials([paper.trial("imbic", level, 1 + level) for level in (0, 1, 2)])
    runs = {
        kernel: jax.jit(
            jax.vmap(lambda t, n=aj.Numerics(solver=solver(kernel=kernel), substeps=5): aj.simulate(t, fd, numerics=n))
        )(trials)
        for kernel in solver.KERNELS
    }
    for name in ("x", "fh", "q"):
        a, b = np.asarray(getattr(runs["fast"], name)), np.asarray(getattr(runs["reference"], name))
        a, b = a - a[:, :1], b - b[:, :1]
        scale = np.abs(b).max(axis=(1, 2), keepdims=True)
        assert np.all(np.abs(a - b) <= 1e-9 * scale), (name, (np.abs(a - b) / scale).max())


def test_bad_options_are_refused_with_the_allowed_choices():
    with pytest.raises(ValueError, match="ARK3: unknown kernel 'grad'; allowed: 'fast', 'reference'"):
        aj.solvers.ARK3(kernel="grad")
    with pytest.raises(ValueError, match="ARK4: unknown kernel 'gpu'; allowed: 'fast', 'reference'"):
        aj.solvers.ARK4(kernel="gpu")
    with pytest.raises(ValueError, match="substeps"):
        aj.Numerics(solver=aj.solvers.ARK3(), substeps=0)


@pytest.mark.slow  # about 14 s cold: a coarse batch against its reference
def test_check_numerics_reports_the_error_of_a_coarse_batch():
    """The observed error is the difference from a run at 4x the substeps, on an even sample."""
    trials = aj.batch.stack_trials([paper.trial("pd", 1, loc) for loc in (1, 2, 3, 4)])
    fd = np.stack([np.asarray(_fd())] * 4)
    welch = aj.Welch(512, 384)
    coarse = aj.Numerics(solver=aj.solvers.RK4(), substeps=2)
    check = aj.batch.check_numerics(trials, fd, numerics=coarse, sample=2, welch=welch)
    np.testing.assert_array_equal(check.indices, [0, 3])
    assert check.refined == aj.Numerics(solver=aj.solvers.RK4(), substeps=8) and check.diverged == 0
    fine = aj.batch.assess_batch(trials, fd, aj.simulate_batch(trials, fd, numerics=check.refined), welch)
    np.testing.assert_allclose(check.phi_T_refined, fine.phi_T[[0, 3]], rtol=1e-12)
    expected = np.abs(check.phi_T - check.phi_T_refined) / check.phi_T_refined
    assert check.max_rel_error == pytest.approx(expected.max()) and 0 < check.max_rel_error < 1e-2
