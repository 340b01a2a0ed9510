"""Ensembles of one reach: ``simulate_ensemble``, the ``Ensemble`` container (arrays, a lab's
files) and the classical route ``estimate_ensemble``: its answer on a noise-free ensemble, its
warnings and refusals. Its coverage over Monte Carlo ensembles is ``armimp_bench.movement``'s."""

import jax
import numpy as np
import pytest

import armimp_jax as aj
from armimp_jax import presets

NUMERICS = aj.Numerics(solver=aj.solvers.RK4(), substeps=10)
KNOTS = (0.2, 0.35, 0.5)
SAMPLES = 800


def _arm():
    """A 4 cm reach from 0.2 s to 0.5 s, K dipping to half at mid-reach (knots ``KNOTS``)."""
    still = presets.arm(3)
    start = np.asarray(still.endpoint)
    path = aj.MinimumJerk(start=start, end=start + np.array([0.0, 0.04]), onset=0.2, duration=0.3)
    k = aj.Profile(times=KNOTS, values=np.asarray([1.0, 0.5, 1.0])[:, None, None] * still.stiffness)
    return aj.Arm(mass=still.mass, damping=still.damping, stiffness=k, endpoint=path)


@pytest.fixture(scope="module")
def quiet():
    """20 noise-free repetitions (the fewest that three knots allow are 15)."""
    trial = aj.make_trial(aj.PD(), arm=_arm(), friction=aj.NO_FRICTION)
    family = aj.signals.PaperNoise(peak=2.25)
    return aj.simulate_ensemble(
        trial, family, key=jax.random.key(0), repetitions=20, samples=SAMPLES, numerics=NUMERICS
    )


# --- simulate_ensemble ---------------------------------------------------------------------


def test_each_repetition_has_its_own_draws_and_more_repetitions_keep_the_first(quiet):
    assert quiet.x.shape == quiet.fh.shape == quiet.f_delta.shape == (20, SAMPLES, 2)
    assert not quiet.diverged.any()
    assert np.all(np.std(quiet.f_delta, axis=0)[1:] > 0)  # no two perturbations alike
    trial = quiet.trial
    fewer = aj.simulate_ensemble(
        trial,
        aj.signals.PaperNoise(peak=2.25),
        key=jax.random.key(0),
        repetitions=2,
        samples=SAMPLES,
        numerics=NUMERICS,
    )
    np.testing.assert_array_equal(fewer.f_delta, quiet.f_delta[:2])
    np.testing.assert_allclose(fewer.fh, quiet.fh[:2], rtol=0, atol=1e-12)  # another batch size: round-off
    given = aj.simulate_ensemble(trial, quiet.f_delta[:2], key=jax.random.key(0), numerics=NUMERICS)
    np.testing.assert_allclose(given.x, quiet.x[:2], rtol=0, atol=1e-15)


def test_an_ensemble_with_noise_draws_it_anew_for_each_repetition():
    trial = aj.make_trial(aj.PD(), arm=_arm(), friction=aj.NO_FRICTION, sensors=aj.Sensors(force_noise=0.05))
    same = np.zeros((2, 300, 2))  # one perturbation for both repetitions: what differs is the noise
    ens = aj.simulate_ensemble(trial, same, key=jax.random.key(1), numerics=NUMERICS)
    assert np.std(ens.fh[0] - ens.fh[1]) > 0.05  # two independent draws of 0.05 N: 0.07 N


def test_simulate_ensemble_refuses_in_one_line():
    trial = aj.make_trial(aj.PD(), arm=_arm(), friction=aj.NO_FRICTION)
    with pytest.raises(ValueError, match=r"one perturbation for every repetition leaves nothing .* \(R, N, 2\)"):
        aj.simulate_ensemble(trial, np.zeros((100, 2)), key=jax.random.key(0))
    with pytest.raises(ValueError, match="a perturbation family needs repetitions= and samples="):
        aj.simulate_ensemble(trial, aj.signals.PaperNoise(peak=1.0), key=jax.random.key(0))
    with pytest.raises(ValueError, match="repetitions=3 but the perturbation array holds 2"):
        aj.simulate_ensemble(trial, np.zeros((2, 100, 2)), key=jax.random.key(0), repetitions=3)


# --- the container -------------------------------------------------------------------------


def _lab(reps=4, n=50, seed=0):
    rng = np.random.default_rng(seed)
    base = np.array([-0.3, 0.3]) + np.linspace(0, 0.1, n)[:, None] * np.array([0.0, 1.0])
    x = base + 1e-3 * rng.normal(size=(reps, n, 2))
    return dict(x=x, fh=rng.normal(size=(reps, n, 2)), f_delta=rng.normal(size=(reps, n, 2)))


def test_an_ensemble_from_arrays_or_a_list_of_them():
    lab = _lab()
    ens = aj.Ensemble(**lab)
    assert (ens.repetitions, ens.samples) == (4, 50)
    listed = aj.Ensemble(**{k: list(v) for k, v in lab.items()})
    np.testing.assert_array_equal(listed.x, ens.x)
    np.testing.assert_allclose(ens.times[-1], 0.049)
    kept = aj.Ensemble(**lab, diverged=[False, True, False, False]).sound()
    assert kept.repetitions == 3
    np.testing.assert_array_equal(kept.fh, lab["fh"][[0, 2, 3]])


def test_an_ensemble_of_repetitions_that_are_not_one_reach_is_refused_in_one_line():
    lab = _lab()
    short = [*lab["x"][:3], lab["x"][3][:40]]
    with pytest.raises(ValueError, match="repetition 3 holds 40 samples and repetition 0 50: every repetition must"):
        aj.Ensemble(x=short, fh=list(lab["fh"]))
    other = lab["x"].copy()
    other[2] += np.array([0.05, 0.0])  # a reach to another target
    stray = r"repetition 2 strays [0-9.]+ cm RMS from the others' median path \(more than 2 cm\)"
    with pytest.raises(ValueError, match=stray):
        aj.Ensemble(x=other, fh=lab["fh"])
    with pytest.raises(ValueError, match=r"needs at least 2 repetitions"):
        aj.Ensemble(x=lab["x"][:1], fh=lab["fh"][:1])
    with pytest.raises(ValueError, match=r"f_delta must have the shape of x \(4, 50, 2\), got \(4, 49, 2\)"):
        aj.Ensemble(x=lab["x"], fh=lab["fh"], f_delta=lab["f_delta"][:, :49])


def test_a_labs_ensemble_from_its_files(tmp_path):
    lab = _lab()
    paths = []
    for r in range(4):
        path = tmp_path / f"reach{r}.npz"
        np.savez(path, **{k: v[r] for k, v in lab.items()}, time=np.arange(50) * 0.002)
        paths.append(path)
    ens = aj.load_ensemble(paths)
    np.testing.assert_array_equal(ens.x, lab["x"])
    np.testing.assert_array_equal(ens.f_delta, lab["f_delta"])
    assert ens.period == pytest.approx(0.002)
    np.savez(paths[1], **{k: v[1][:30] for k, v in lab.items()})
    with pytest.raises(ValueError, match="repetition 1 holds 30 samples"):
        aj.load_ensemble(paths)


# --- the classical route -------------------------------------------------------------------


def test_a_noise_free_ensemble_gives_the_arm_at_every_knot(quiet):
    """Within 1% (what remains is the differences' and the sampling's own error: 0.1-0.4%)."""
    fit = aj.estimate_ensemble(quiet, window=0.1)
    arm = quiet.trial.arm
    np.testing.assert_array_equal(fit.knots, KNOTS)
    np.testing.assert_allclose(fit.mass, arm.mass, rtol=0, atol=0.01 * np.abs(arm.mass).max())
    for j, t in enumerate(KNOTS):
        still = arm.at(t)
        np.testing.assert_allclose(fit.stiffness[j], still.stiffness, rtol=0, atol=0.01 * np.abs(still.stiffness).max())
        np.testing.assert_allclose(fit.damping[j], still.damping, rtol=0, atol=0.01 * np.abs(still.damping).max())
    assert fit.dof == 19
    assert any("only 20 repetitions" in w for w in fit.warnings)
    low, high = fit.interval("stiffness")
    assert np.all(low < fit.stiffness) and np.all(fit.stiffness < high)
    assert len(fit.table()) == 4 * (1 + 2 * len(KNOTS))
    assert "K" in fit.summary()


def test_warnings_a_short_window_and_a_knot_the_perturbation_misses(quiet):
    fit = aj.estimate_ensemble(quiet, window=0.02)
    assert any("the window (+-20 ms) is short" in w for w in fit.warnings)
    f = quiet.f_delta.copy()
    f[:, 220:480] = 0.0  # the robot stops perturbing from 0.22 s to 0.48 s, around the middle knot
    gap = aj.simulate_ensemble(quiet.trial, f, key=jax.random.key(0), numerics=NUMERICS)
    fit = aj.estimate_ensemble(gap, knots=KNOTS)
    missed = [w for w in fit.warnings if "misses the knot" in w]
    assert len(missed) == 1 and "knot at 0.35 s" in missed[0]


def test_estimate_ensemble_refuses_in_one_line_before_computing(quiet):
    blind = aj.Ensemble(x=quiet.x, fh=quiet.fh)
    with pytest.raises(ValueError, match="holds no perturbations .* the estimate's instrument"):
        aj.estimate_ensemble(blind, knots=KNOTS)
    few = aj.Ensemble(x=quiet.x[:14], fh=quiet.fh[:14], f_delta=quiet.f_delta[:14])
    with pytest.raises(
        ValueError, match="14 repetitions cannot give intervals for 3 knots: .* at least 15 repetitions"
    ):
        aj.estimate_ensemble(few, knots=KNOTS)
    with pytest.raises(ValueError, match="leave the record"):
        aj.estimate_ensemble(quiet, knots=(0.2, 0.75))
    with pytest.raises(ValueError, match=r"cutoff must lie in \(0, 500\) Hz"):
        aj.estimate_ensemble(quiet, cutoff=600.0)
    with pytest.raises(ValueError, match="knots must be increasing"):
        aj.estimate_ensemble(quiet, knots=(0.3, 0.2))
