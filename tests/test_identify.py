"""Model-based identification through the closed loop (issue 27): exact recovery on noise-free
data, the cost's gradient, one-line errors before long work, predict_se against Monte Carlo."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import armimp_jax as aj
from armimp_jax import paper
from armimp_jax._identification import layout as lay
from armimp_jax._identification import model_fit as mf

NUM = aj.IDENTIFY_NUMERICS
ARM = ("arm.mass", "arm.damping", "arm.stiffness")


def _trial(arm=None, friction=None, **kw):
    return aj.make_trial(
        aj.PD(),
        arm=paper.arm(2) if arm is None else arm,
        friction=aj.LuGre(0.8, 1.2) if friction is None else friction,
        **kw,
    )


def _start():
    true = paper.arm(2)
    scaled = aj.Arm(
        np.asarray(true.mass) * 1.15, np.asarray(true.damping) * 0.8, np.asarray(true.stiffness) * 1.2, true.endpoint
    )
    return _trial(scaled, aj.LuGre(0.6, 1.2))


def test_recovers_known_parameters_from_noise_free_data():
    truth = _trial()
    f = aj.perturbation(jax.random.key(0), 2000, 10.0)
    sim = aj.simulate(truth, f, numerics=NUM)
    res = aj.identify(_start(), f, sim.x, sim.fh, free=ARM + ("friction.tau_c",))
    assert res.converged, res.message
    for name, want in (
        ("arm.mass", truth.arm.mass),
        ("arm.damping", truth.arm.damping),
        ("arm.stiffness", truth.arm.stiffness),
        ("friction.tau_c", truth.friction.tau_c),
    ):
        np.testing.assert_allclose(res.values[name], want, rtol=1e-6, atol=1e-9 * np.abs(want).max())
    assert np.all(res.vaf_position > 99.9999) and np.all(res.vaf_force > 99.9999)


@pytest.mark.slow  # ~35 s; the full-matrix fit is checked fast above
def test_symmetric_option_gives_a_symmetric_matrix_of_three_numbers():
    truth = _trial()
    f = aj.perturbation(jax.random.key(1), 2000, 10.0)
    sim = aj.simulate(truth, f, numerics=NUM)
    arm = paper.arm(2)
    start = _trial(aj.Arm(np.eye(2), arm.damping, arm.stiffness, arm.endpoint))
    res = aj.identify(start, f, sim.x, sim.fh, free=("arm.mass",), symmetric=("arm.mass",), max_steps=30)
    m = res.values["arm.mass"]
    assert m[0, 1] == m[1, 0]
    # the true mass is not symmetric: the fit is the best symmetric one, not the truth
    assert abs(m[0, 1] - np.asarray(truth.arm.mass)[0, 1]) > 1e-3


def test_cost_gradient_matches_finite_differences():
    truth = _trial(sensors=aj.Sensors(force_noise=0.05), voluntary=aj.VoluntaryForce(0.3, 2.0))
    f = aj.perturbation(jax.random.key(2), 1500, 8.0)
    rec = aj.simulate(truth, f, key=jax.random.key(3), numerics=NUM)
    y = jnp.concatenate([rec.x, rec.fh], axis=1)
    layout = lay.make_layout(ARM + ("friction.tau_c", "friction.tau_s"))
    model = _start()
    p = lay.pack(layout, model)
    scale = jnp.std(y, axis=0)

    def cost(q):
        r = mf.residual(layout, model, q, f, y, scale, None, NUM)
        return 0.5 * r @ r

    grad = jax.grad(cost)(p)
    cost_jit = jax.jit(cost)
    for i in (0, 5, 11, 12, 14):  # mass, damping, stiffness entries, log tau_c, log(tau_s - tau_c)
        h = 1e-6 * max(1.0, abs(float(p[i])))
        e = jnp.zeros_like(p).at[i].set(h)
        fd = (cost_jit(p + e) - cost_jit(p - e)) / (2 * h)
        np.testing.assert_allclose(grad[i], fd, rtol=1e-4)


def test_bad_input_is_a_one_line_error_before_long_work():
    truth = _trial()
    f = np.asarray(aj.perturbation(jax.random.key(4), 2000, 5.0))
    sim = aj.simulate(truth, jnp.asarray(f), numerics=NUM)
    x, fh = np.asarray(sim.x), np.asarray(sim.fh)
    bad = x.copy()
    bad[123, 1] = np.nan
    with pytest.raises(ValueError, match=r"identify: x holds a non-finite value.*nan.*sample 123, column 1"):
        aj.identify(truth, f, bad, fh, free=ARM)
    with pytest.raises(ValueError, match="same length"):
        aj.identify(truth, f, x[:-1], fh, free=ARM)
    with pytest.raises(ValueError, match=r"unknown parameter 'arm.inertia'; valid names: arm.mass, arm.damping"):
        aj.identify(truth, f, x, fh, free=("arm.inertia",))
    with pytest.raises(ValueError, match="symmetric names 'arm.damping', which is not a free arm matrix"):
        aj.identify(truth, f, x, fh, free=("arm.mass",), symmetric=("arm.damping",))
    unstable = _trial(aj.Arm(np.eye(2), np.zeros((2, 2)), -1500.0 * np.eye(2), paper.arm(2).endpoint))
    with pytest.raises(ValueError, match="diverges at the starting values"):
        aj.identify(unstable, f, x, fh, free=ARM)
    with pytest.raises(ValueError, match="friction.tau_s must start above tau_c"):
        aj.identify(_trial(friction=aj.LuGre(0.8, 0.8)), f, x, fh, free=("friction.tau_s",))


@pytest.mark.slow
def test_predict_se_matches_the_spread_of_identify_over_noise_draws():
    """40 recordings under new noise, identify from the truth: the spread of each estimate
    against predict_se (issue 27: within 0.7-1.4x), and the fall with the record length."""
    truth = _trial(
        friction=aj.LuGre(0.2, 0.3),
        sensors=aj.Sensors(force_noise=0.05, encoder_counts=2**18),
        voluntary=aj.VoluntaryForce(0.3, 2.0),
    )
    free = ARM + ("friction.tau_c",)
    f = aj.perturbation(jax.random.key(5), 3000, 10.0)
    estimates = []
    for seed in range(40):
        rec = aj.simulate(truth, f, key=jax.random.key(100 + seed), numerics=NUM)
        res = aj.identify(truth, f, rec.x, rec.fh, free=free, bootstrap=20, key=jax.random.key(seed))
        estimates.append(np.concatenate([np.ravel(res.values[n]) for n in free]))
    spread = np.std(np.stack(estimates), axis=0, ddof=1)
    pred = aj.predict_se(truth, f, free=free, bootstrap=200)
    predicted = np.concatenate([np.ravel(pred.se[n]) for n in free])
    ratio = predicted / spread
    # 40 draws: the spread itself is good to about +-11% (1 SD)
    assert np.all((ratio > 0.7) & (ratio < 1.4)), ratio
    longer = aj.predict_se(truth, aj.perturbation(jax.random.key(5), 12000, 10.0), free=free, bootstrap=200)
    shrink = predicted / np.concatenate([np.ravel(longer.se[n]) for n in free])
    assert np.all((shrink > 1.5) & (shrink < 2.7)), shrink  # 1 / sqrt(N): 2 for four times the record


@pytest.mark.slow  # about a minute: reverse mode through the Jacobian of the simulation
def test_predict_se_is_differentiable_in_the_perturbation():
    # no friction: the simulation is smooth in f, so finite differences are a fair reference
    truth = _trial(friction=aj.NO_FRICTION, sensors=aj.Sensors(force_noise=0.05))
    f = aj.perturbation(jax.random.key(6), 200, 10.0)

    def total(fd):
        return aj.predict_se(truth, fd, free=("arm.stiffness",), bootstrap=10).se["arm.stiffness"].sum()

    g = jax.grad(total)(f)
    assert g.shape == f.shape and np.all(np.isfinite(np.asarray(g))) and np.abs(np.asarray(g)).max() > 0
    d = jnp.asarray(np.random.default_rng(0).standard_normal(f.shape))
    h = 1e-4
    fd = (total(f + h * d) - total(f - h * d)) / (2 * h)
    np.testing.assert_allclose(jnp.vdot(g, d), fd, rtol=1e-3)


@pytest.mark.slow  # two noisy fits with bootstrap: ~1 min on 2 shared cores
def test_linearity_check_is_quiet_for_small_noise_and_flags_the_persons_force():
    """The intervals rest on a fit linear in the noise: with sensor noise alone one more
    Gauss-Newton step on re-simulated recordings moves nothing (measured 0.01 SE); with the
    person's 0.3 N force in the loop it moves the damping by ~0.9 SE and the result says so."""
    f = aj.perturbation(jax.random.key(2), 2000, 10.0)
    out = {}
    for name, sensors, voluntary in (
        ("quiet", aj.Sensors(force_noise=0.005), None),
        ("person", aj.Sensors(force_noise=0.05), aj.VoluntaryForce(0.3, 2.0)),
    ):
        truth = _trial(sensors=sensors, voluntary=voluntary)
        rec = aj.simulate(truth, f, key=jax.random.key(3), numerics=aj.IDENTIFY_NUMERICS)
        out[name] = aj.identify(truth, f, rec.x, rec.fh, free=ARM, bootstrap=10)
    quiet, person = out["quiet"], out["person"]
    assert quiet.converged and quiet.intervals_reliable and quiet.linearity < 0.1 and not quiet.warnings
    assert person.linearity > 0.5 and not person.intervals_reliable
    assert "intervals unreliable" in person.warnings[0] and "WARNING: intervals unreliable" in person.summary()


def test_band_weights_pass_the_band_and_refuse_a_bad_one():
    w = np.asarray(mf.band_weights(1000, 3.0, 25.0).weights)  # 1 Hz bins
    assert w.shape == (501,)
    np.testing.assert_array_equal(w[3:26], 1.0)
    np.testing.assert_array_equal(w[:2], 0.0)
    np.testing.assert_array_equal(w[27:], 0.0)
    e = np.random.default_rng(0).standard_normal((1000, 4))
    filtered = np.asarray(mf.apply_noise_model(mf.band_weights(1000, 3.0, 25.0), jnp.asarray(e)))
    spectrum = np.abs(np.fft.rfft(filtered, axis=0))
    assert spectrum[40:].max() < 1e-9 * spectrum[3:26].max()  # nothing left outside the band
    with pytest.raises(ValueError, match=r"identify: band must satisfy 0 <= low < high < 500 Hz"):
        mf.check_band((30.0, 20.0), 1000, "identify")
    with pytest.raises(ValueError, match=r"band must be \(low, high\)"):
        mf.check_band(5.0, 1000, "identify")
