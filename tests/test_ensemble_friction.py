"""The model route over an ensemble through friction (``ensemble_friction.py``): the controller
replayed along the planned path, the statistics' covariance from each reach's spread, and (slow)
one ensemble identified through LuGre with ``tau_c`` free."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import armimp_jax as aj
from armimp_bench import movement as mv
from armimp_bench import movement_model as mm
from armimp_jax._identification import auxiliary
from armimp_jax._identification import ensemble_friction as ef
from armimp_jax._identification import path as ph


def test_the_replayed_command_follows_the_planned_path_as_the_simulation_did():
    """With ideal sensors PD's replay sees what the controller saw, but for the velocity (backward
    differences where the loop measured it): the command agrees to that difference, and a replay
    that held the start as set point (as before reaches) would miss by the reach's 12 cm of spring.
    (IMBIC's command integrates, so its replay drifts with the velocity's difference, still or
    moving: a statistic the simulation replays alike, consistent but less telling.)"""
    controller = aj.PD()
    trial = aj.make_trial(controller, arm=mv.base_arm(), friction=aj.NO_FRICTION)
    f = jnp.asarray(mm.bound_draws(draws=1)[0])
    sim = aj.simulate(trial, f)
    replayed = auxiliary.replay_command(trial, f, sim.x, sim.fh)
    gap = np.abs(np.asarray(replayed - sim.fu))[1:].max()
    scale = np.abs(np.asarray(sim.fu)).max()
    assert gap < 0.02 * scale, (gap, scale)
    arm = mv.base_arm()
    held = aj.Arm(mass=arm.mass, damping=arm.damping, stiffness=arm.stiffness.values[0], endpoint=arm.start)
    still = aj.make_trial(controller, arm=held, friction=aj.NO_FRICTION)  # the same controller, no path to follow
    assert np.abs(np.asarray(auxiliary.replay_command(still, f, sim.x, sim.fh) - sim.fu)).max() > 10 * gap


def test_omega_is_the_covariance_of_the_ensemble_mean_of_independent_reaches():
    """``sum_r cov(c_r) / R^2`` from the draws' spread per reach, against the spread of the mean over
    many ensembles drawn with each reach's own mean and covariance."""
    rng = np.random.default_rng(0)
    r, m, draws = 6, 3, 4000
    means = rng.normal(size=(r, m)) * 5.0  # each reach its own mean (its own perturbation)
    chol = rng.normal(size=(r, m, m)) * 0.3
    contrib = means[None] + np.einsum("rij,drj->dri", chol, rng.normal(size=(draws, r, m)))
    omega = ef.omega(contrib)
    exact = np.einsum("rij,rkj->ik", chol, chol) / r**2
    np.testing.assert_allclose(omega, exact, rtol=0.1, atol=0.02 * np.abs(exact).max())
    spread = np.cov(contrib.mean(axis=1).T)
    np.testing.assert_allclose(omega, spread, rtol=0.15, atol=0.03 * np.abs(exact).max())


@pytest.mark.slow  # about 3 minutes cold: 40 reaches identified through friction
def test_one_ensemble_through_lugre_is_recovered_with_tau_c_a_nuisance():
    truth, _, _ = mm.case_trials("imbic-lugre")
    ens = aj.simulate_ensemble(
        truth, aj.signals.PaperNoise(peak=mv.PEAK), key=jax.random.key(3), repetitions=40, samples=1600
    )
    fit = aj.identify(truth, ens, free=ph.ARM)  # tau_c freed as the friction's nuisance
    assert fit.converged, fit.message
    assert fit.labels[-2:] == ["friction.tau_c[0]", "friction.tau_c[1]"]
    z = (fit.estimate - mm.true_values("imbic-lugre")) / fit.se
    assert np.all(np.abs(z) < 4.0), dict(zip(fit.labels, np.round(z, 2), strict=True))
    assert fit.settings["draws"] == ef.DRAWS and fit.seconds > 0
