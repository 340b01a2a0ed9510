"""The bound along a reach (``crlb`` of a moving arm, ``reaches_for``) and the model route over an
ensemble (``identify(model, ensemble=...)``): the time-varying filter against the still arm's
steady one, whitened noise of unit variance, refusals in one line before any computation."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import armimp_jax as aj
from armimp_bench import movement as mv
from armimp_jax._identification import bound, indirect, kalman, linear
from armimp_jax._identification import layout as lay
from armimp_jax._identification import path as ph
from armimp_jax._identification import path_bound as pb
from armimp_jax.study.sweep import coverage as cov

NUM = indirect.IDENTIFY_NUMERICS


def _still_trial():
    arm = mv.base_arm()
    still = aj.Arm(mass=arm.mass, damping=arm.damping, stiffness=arm.stiffness.values[0], endpoint=arm.start)
    return aj.make_trial(aj.PD(), arm=still, friction=aj.NO_FRICTION, **cov.noise())


def _draws(n, count=2, peak=mv.PEAK):
    fam = aj.signals.PaperNoise(peak=peak)
    return np.stack([np.asarray(fam.signal(jax.random.key(100 + i), n, 0.001)) for i in range(count)])


@pytest.mark.slow  # 32 s: the loop along 4 s compiled
def test_held_still_the_filter_along_the_path_is_the_steady_filter_and_the_response_the_linear_one():
    # Held still, the loop along the path is the loop at rest: the time-varying filter from the exact
    # start tends to the steady-state one (innovations' covariance at the end of 4 s equal to 1e-6),
    # and whitens the linear loop's response derivative to the still bound's SEs (0.3%: the starts differ).
    # The simulator's own response derivative differs from the linearised loop's by 0.2-0.5% (the
    # robot's kinematics at the paper's amplitude, second order; the same with the paper's RK4).
    trial, f = _still_trial(), _draws(4000, 1)[0]
    layout = bound._bound_layout(bound.ARM, (), "test")
    dy = jax.jit(lambda tr: bound.response_derivative(layout, tr, lay.pack_arm(layout, tr), f)[1])(trial)
    steady = kalman.innovations_filter(linear.loop_of(trial))
    along = jax.jit(lambda tr: ph.path_filter(ph.path_loop(tr, f.shape[0], NUM)))(trial)
    end = np.asarray(along.chol[-1] @ along.chol[-1].T) * np.outer(along.scale, along.scale)
    np.testing.assert_allclose(end, np.asarray(steady.cov) * np.outer(steady.scale, steady.scale), rtol=1e-6)
    w = ph.whiten(along, dy)
    se_along = np.sqrt(np.diag(np.linalg.inv(np.asarray(jnp.einsum("kip,kiq->pq", w, w)))))
    se_steady = np.sqrt(np.diag(np.linalg.inv(np.asarray(kalman.information(steady, dy)))))
    np.testing.assert_allclose(se_along, se_steady, rtol=5e-3)  # the starts differ: exact vs steady (0.3% on M)
    knots = ph.knot_layout(trial)
    jac = jax.jit(lambda tr: ph.response_jacobians(knots, tr, ph.pack(knots, tr), f[None], NUM)[1][0])(trial)
    gap = np.linalg.norm(np.asarray(jac - dy), axis=(0, 1)) / np.linalg.norm(np.asarray(dy), axis=(0, 1))
    assert np.all(gap < 0.01), gap


@pytest.mark.slow  # 40 s: an ensemble and the loop along the reach compiled
def test_the_time_varying_filter_whitens_a_reachs_noise_to_unit_variance():
    # 20 reaches without perturbation: what is left is the noise alone, non-stationary along the
    # path; its innovations must be white of unit variance on every channel (a variance estimate
    # over 20 x 1600 samples has an SE of about 0.008).
    trial = mv.base_trial(aj.IMBIC())
    n, r = 1600, 20
    ens = aj.simulate_ensemble(trial, np.zeros((r, n, 2)), key=jax.random.key(1), numerics=NUM)
    y = jnp.asarray(np.concatenate([ens.x - np.asarray(trial.x0), ens.fh], axis=2))
    filt = jax.jit(lambda t: ph.path_filter(ph.path_loop(t, n, NUM)))(trial)
    w = np.asarray(ph.whiten_centred(filt, y))
    variance = np.mean(w**2, axis=(0, 1)) * r / (r - 1)
    np.testing.assert_allclose(variance, 1.0, atol=0.05)
    lag1 = np.mean(w[:, 1:] * w[:, :-1], axis=(0, 1))
    np.testing.assert_allclose(lag1, 0.0, atol=0.05)


def test_reaches_for_counts_from_the_bound_and_refuses_a_bad_precision_at_once():
    labels = ["arm.stiffness@t=0.8[0,0]", "arm.stiffness@t=0.8[1,1]"]
    bound = pb.PathBound(labels, np.array([100.0, 50.0]), np.array([150.0, 30.0]), np.eye(2), np.eye(2), 8, "x")
    # R - 1 = (1.96 * relative SE / precision)^2, rounded up: the mean path takes one reach
    z = 1.959963984540054
    expected = {labels[0]: int(np.ceil((z * 1.5 / 0.1) ** 2)) + 1, labels[1]: int(np.ceil((z * 0.6 / 0.1) ** 2)) + 1}
    assert bound.reaches_for(0.1) == expected
    with pytest.raises(ValueError, match=r"precision must lie in \(0, 1\).*got 10"):
        aj.reaches_for(mv.base_trial(), np.ones((8, 2)), precision=10)
    with pytest.raises(ValueError, match="level must lie"):
        aj.reaches_for(mv.base_trial(), np.ones((8, 2)), level=95)


def _ensemble(reps=10, f=True, period=0.001, same=False):
    n = 1600  # the base reach's record: 1.6 s
    x = np.zeros((reps, n, 2)) + np.linspace(0, 1e-3, n)[None, :, None]
    draws = np.random.default_rng(0).normal(size=(1 if same else reps, n, 2))
    fd = np.broadcast_to(draws, (reps, n, 2)) if f else None
    return aj.Ensemble(x=x, fh=np.zeros((reps, n, 2)), f_delta=fd, period=period)


def _sensors(**kw):
    return aj.make_trial(
        aj.PD(),
        arm=mv.base_arm(),
        friction=aj.NO_FRICTION,
        sensors=aj.Sensors(**kw),
        voluntary=aj.VoluntaryForce(0.3, 2.0),
    )


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(ensemble=_ensemble(f=False)), "holds no perturbations"),
        (dict(ensemble=_ensemble(reps=5)), "5 sound repetitions; the model route needs at least 8"),
        (dict(ensemble=_ensemble(period=0.002)), "sampled every 0.002 s"),
        (dict(ensemble=_ensemble(), free=("arm.stiffness", "friction.tau_c")), "friction.tau_c is free but the model"),
        (dict(ensemble=_ensemble(), free=("robot.inertia",)), "free takes arm matrices"),
        (dict(ensemble=_ensemble(), x=np.ones((64, 2))), "x, fh and calibration stay None"),
        (dict(ensemble=_ensemble(same=True)), "every reach has the same perturbation"),
        (dict(ensemble=_ensemble(), trial=_sensors(force_noise=0.05)), "must each carry reading noise"),
        (
            dict(ensemble=_ensemble(), trial=_sensors(force_noise=0.05, encoder_counts=2**18, force_gain=1.02)),
            "uncalibrated force transducer",
        ),
        (
            dict(
                ensemble=aj.Ensemble(
                    x=np.zeros((10, 600, 2)),
                    fh=np.zeros((10, 600, 2)),
                    f_delta=np.random.default_rng(1).normal(size=(10, 600, 2)),
                )
            ),
            "knot at 0.6 s lies outside the record",
        ),
    ],
)
def test_identify_over_an_ensemble_refuses_bad_input_in_one_line(kwargs, match):
    free, trial = kwargs.pop("free", ph.ARM), kwargs.pop("trial", mv.base_trial())
    with pytest.raises(ValueError, match=match) as info:
        aj.identify(trial, kwargs.pop("ensemble"), free=free, **kwargs)
    assert "\n" not in str(info.value)


def test_knot_names_carry_the_knot_and_round_trip():
    trial = mv.base_trial()
    layout = ph.knot_layout(trial)
    assert layout.matrix_names()[:3] == ["arm.mass", "arm.damping", "arm.stiffness@t=0.4"]
    assert "arm.stiffness@t=0.8[1,1]" in layout.labels()
    p = ph.pack(layout, trial)
    again = ph.pack(layout, ph.with_values(layout, trial, p * 2.0))
    np.testing.assert_array_equal(np.asarray(again), 2.0 * np.asarray(p))


@pytest.mark.parametrize(
    "friction, free",
    [(aj.CoulombViscous(0.5, 0.1), ph.ARM), (aj.LuGre(0.5, 0.75), ph.ARM + ("friction.tau_s",))],
)
def test_identify_over_an_ensemble_refuses_friction_it_has_not_measured_saying_what_to_do(friction, free):
    trial = aj.make_trial(aj.IMBIC(), arm=mv.base_arm(), friction=friction, **cov.noise())
    with pytest.raises(ValueError, match="measured for LuGre with friction.tau_c.*estimate_ensemble") as info:
        aj.identify(trial, _ensemble(), free=free)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("controller", [aj.PD(), aj.Admittance()])
def test_identify_over_an_ensemble_through_friction_refuses_a_controller_it_has_not_measured(controller):
    trial = aj.make_trial(controller, arm=mv.base_arm(), friction=aj.LuGre(0.5, 0.75), **cov.noise())
    with pytest.raises(ValueError, match="under IMBIC alone, not under .*did not settle.*estimate_ensemble") as e:
        aj.identify(trial, _ensemble(), free=ph.ARM)
    assert "\n" not in str(e.value) and type(controller).__name__ in str(e.value)


def test_an_envelope_moves_the_perturbation_into_the_reach_keeping_its_rms_and_peak():
    raw_family, n = aj.signals.PaperNoise(peak=mv.PEAK), 1600
    shape = aj.experiment.Envelope(raw_family, 0.4, 1.2, 0.3, 1.0)
    key = jax.random.key(3)
    raw, shaped = np.asarray(raw_family.signal(key, n, 0.001)), shape.signal(key, n, 0.001)
    assert np.all(np.max(np.abs(shaped), axis=0) <= np.max(np.abs(raw), axis=0))
    # the RMS over the record is the raw draw's, less what the clip at the peak takes (a few percent)
    np.testing.assert_allclose(np.sqrt(np.mean(shaped**2, 0)), np.sqrt(np.mean(raw**2, 0)), rtol=0.05)
    inside = slice(450, 1150)  # past the ramps
    gain = np.sqrt(np.mean(shaped[inside] ** 2) / np.mean(raw[inside] ** 2))
    outside = np.r_[0:300, 1300:1600]
    assert gain / np.sqrt(np.mean(shaped[outside] ** 2) / np.mean(raw[outside] ** 2)) == pytest.approx(
        1 / 0.3, rel=0.05
    )
    uniform = aj.experiment.Envelope(raw_family, 0.4, 1.2, 1.0, 1.0).signal(key, n, 0.001)
    np.testing.assert_allclose(uniform, raw, rtol=1e-12)


@pytest.mark.slow  # about 2 minutes: the bound of four designs
def test_design_reach_scores_designs_on_the_bound_and_keeps_the_paper_s_as_reference():
    trial = aj.make_trial(aj.PD(), arm=mv.base_arm(), friction=aj.NO_FRICTION, **cov.noise())
    shapes = (("uniform", 1.0, 1.0), ("reach", 0.3, 1.0))
    d = aj.experiment.design_reach(
        trial, aj.signals.PaperNoise(peak=mv.PEAK), samples=1600, shapes=shapes, gain_scales=(1.0, 0.5), draws=2
    )
    assert len(d.candidates) == 4 and d.paper["shape"] == "uniform" and d.paper["gain_scale"] == 1.0
    assert d.best["worst"] == min(c["worst"] for c in d.candidates if c["within"])
    assert d.ratio == pytest.approx(d.best["worst"] / d.paper["worst"])
    # the reach's own perturbation tells the mid-reach stiffness better than the paper's even spread
    assert next(c for c in d.candidates if c["shape"] == "reach" and c["gain_scale"] == 1.0)["worst"] < d.paper["worst"]


@pytest.mark.slow  # about 4 minutes: 12 reaches fitted (twice), refreshed, and refitted at the answer 16 times
def test_the_model_route_ends_where_its_own_linearisation_points_and_widens_to_its_check_s_spread():
    from armimp_bench import movement_model as mm
    from armimp_jax._identification import ensemble_identify as ei
    from armimp_jax._identification import ensemble_search as es

    truth, model, free = mm.case_trials("pd-designed")  # half the gains: the loop bends most
    family = mm.perturbation("pd-designed")
    ens = aj.simulate_ensemble(truth, family, key=jax.random.key(5), repetitions=12, samples=1600)
    fit = aj.identify(model, ens, free=free)
    assert fit.converged and fit.refreshed_step < es.REFRESH_TOLERANCE
    # the bound at the answer, as the noise ratio widens it; the check widens it further, never narrows it
    sound, layout = ei._check(model, ens, free, "test")
    lin = es.linearise(layout, model, fit.estimate, jnp.asarray(sound.f_delta), NUM)
    bound_se = np.sqrt(np.diag(lin.h_inv) * max(fit.noise_ratio, 1.0))
    np.testing.assert_allclose(fit.se, bound_se * np.maximum(fit.spread_ratio, 1.0), rtol=1e-6)
    assert np.all((fit.spread_ratio > 0.4) & (fit.spread_ratio < 2.5))  # 16 refits: about 18% noise per entry
    again = aj.identify(model, ens, free=free)
    np.testing.assert_array_equal(again.se, fit.se)  # the check's draws are fixed: every call the same intervals


@pytest.mark.parametrize("length", [7, 8])
@pytest.mark.parametrize("raw", [False, True])
def test_a_map_split_over_the_devices_is_the_map_for_any_length_and_key_kind(length, raw):
    """``split_over_devices`` on the suite's two devices, the leading axis padded to them and the
    padding dropped on the host: bitwise the map on one device, typed or raw keys alike."""
    assert jax.local_device_count() == 2  # the suite's set-up (conftest): the split is exercised
    x = jnp.arange(length * 3.0).reshape(length, 3)
    keys = jax.random.split(jax.random.PRNGKey(4) if raw else jax.random.key(4), length)

    def fn(xs, ks):
        return jax.vmap(lambda a, k: jnp.sin(a) + jax.random.normal(k, a.shape))(xs, ks), jnp.sum(xs, axis=1)

    (xp, kp), n = ph.padded_for_devices(x, keys)
    assert n == length and xp.shape[0] % 2 == 0
    split = ph.on_host(jax.jit(lambda a, k: ph.split_over_devices(fn, a, k))(xp, kp), n)
    whole = ph.on_host(jax.jit(fn)(x, keys))
    for a, b in zip(split, whole, strict=True):
        np.testing.assert_array_equal(a, b)
