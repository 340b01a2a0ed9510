"""The simulation loop: rest, convergence order, IMBIC's target dynamics, determinism, errors."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.integrate
from helpers import tree_equal, zoh_response

import armimp_jax as aj
from armimp_jax import _batch as sweep
from armimp_jax import paper
from armimp_jax._model.plant import measure, plant_model, rest_state
from armimp_jax._solver.rk4 import rk4_step

CONTROLLERS = ["pd", "imbic"]


@jax.jit(static_argnames="substeps")
def _sim(trial, fd, substeps=100):
    return aj.simulate(trial, fd, numerics=aj.Numerics(solver=aj.solvers.RK4(), substeps=substeps))


@jax.jit(static_argnames="substeps")
def _batch_sim(trials, fds, substeps=100):
    return jax.vmap(lambda t, f: aj.simulate(t, f, numerics=aj.Numerics(solver=aj.solvers.RK4(), substeps=substeps)))(
        trials, fds
    )


@pytest.fixture(scope="module")
def sim():
    return _sim


@pytest.fixture(scope="module")
def batch_sim():
    return _batch_sim


def _fd(n, seed=3, level=1):
    return aj.perturbation(jax.random.PRNGKey(seed), n, paper.perturbation_peak(level))


@pytest.mark.parametrize("acquisition", ["instant", "interval_mean"])
@pytest.mark.parametrize("controller", CONTROLLERS)
def test_rest_is_exact_rest_everywhere(batch_sim, controller, acquisition):
    """Unperturbed, every friction level and location stays exactly (bitwise) at x0."""
    cases = [(f, loc) for f in (0, 1, 2) for loc in (1, 2, 3, 4)]
    params = aj.batch.stack_trials([paper.trial(controller, f, loc, acquisition=acquisition) for f, loc in cases])
    r = batch_sim(params, jnp.zeros((len(cases), 300, 2)), substeps=4)
    x0 = np.asarray(params.x0)[:, None, :]
    np.testing.assert_array_equal(r.x, np.broadcast_to(x0, r.x.shape))
    np.testing.assert_array_equal(r.q, np.broadcast_to(np.asarray(params.q0)[:, None, :], r.q.shape))
    for field in (r.xd, r.fh, r.fu, r.z):
        np.testing.assert_array_equal(field, 0.0)
    assert not np.any(r.diverged)


def test_rk4_is_fourth_order():
    """Smooth case (friction 0), a 20 ms control period so that the step error is visible."""
    base = aj.make_trial(aj.PD(), arm=paper.arm(1), friction=aj.NO_FRICTION, period=0.02)
    fd = 20.0 * _fd(40)

    def run(substeps):
        return np.asarray(aj.simulate(base, fd, numerics=aj.Numerics(solver=aj.solvers.RK4(), substeps=substeps)).q)

    ref = run(256)
    errs = [np.abs(run(s) - ref).max() for s in (1, 2, 4, 8)]
    orders = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
    assert np.all((orders > 3.8) & (orders < 4.3)), orders


def _desired_response(params, fd, period, mass_scale=1.0):
    """IMBIC's target: (M_rd + M_h) xdd + (B_rd + B_h) xd + (K_rd + K_h) e = F_Delta (ZOH), exact."""
    c, arm = params.controller, params.arm
    m = np.asarray(mass_scale * c.m_rd + arm.mass)
    return zoh_response(m, np.asarray(c.b_rd + arm.damping), np.asarray(c.k_rd + arm.stiffness), fd, period)


@pytest.mark.parametrize("accel_estimate", ["velocity", "position"])
@pytest.mark.parametrize("location", [1, 4])
def test_imbic_without_friction_realises_its_desired_dynamics(sim, location, accel_estimate):
    p = paper.trial("imbic", 0, location, accel_estimate=accel_estimate)
    fd = _fd(2000)
    e = np.asarray(sim(p, fd, substeps=10).x - p.x0[None])
    ref = _desired_response(p, fd, p.period)
    rel = np.sqrt(np.mean((e - ref) ** 2) / np.mean(ref**2))
    assert rel < 0.02, rel  # the one-sample delay of time-delay estimation costs ~1%
    # the tolerance discriminates: a target with half the desired robot mass is far off
    wrong = _desired_response(p, fd, p.period, mass_scale=0.5)
    assert np.sqrt(np.mean((e - wrong) ** 2) / np.mean(wrong**2)) > 0.1


def test_friction_locks_pd_in_presliding(sim):
    fd = _fd(1000)
    free = np.asarray(sim(paper.trial("pd", 0, 1), fd, substeps=20).x).std(0)
    stuck = np.asarray(sim(paper.trial("pd", 2, 1), fd, substeps=20).x).std(0)
    assert np.all(stuck < 0.05 * free)


def test_interval_mean_is_the_mean_over_the_period():
    """xbar_k and Fbar_h,k equal Simpson means of finely sampled x and F_h over [t_k-1, t_k].

    The force formula is exact for any friction; the smooth frictionless case lets the
    Simpson reference be accurate enough for a tight check.
    """
    fd = _fd(200)
    p = paper.trial("pd", 0, 2, acquisition="interval_mean")
    substeps = 40
    r = aj.simulate(p, fd, numerics=aj.Numerics(solver=aj.solvers.RK4(), substeps=substeps))
    model = plant_model(p.q0, p.x0, p.arm, p.friction, p.robot)
    h = p.period / substeps

    def period(state, fu):  # replay the recorded commands through the plant, sampling every substep
        def sub(st, _):
            x_i, _, f_i = measure(st, fu, model)
            return rk4_step(st, fu, model, h), (x_i, f_i)

        end, (xs, fs) = jax.lax.scan(sub, state, None, length=substeps)
        x_end, _, f_end = measure(end, fu, model)
        return end, (jnp.concatenate([xs, x_end[None]]), jnp.concatenate([fs, f_end[None]]))

    _, (xs, fs) = jax.jit(lambda fu: jax.lax.scan(period, rest_state(p.q0), fu))(r.fu)
    xbar = scipy.integrate.simpson(np.asarray(xs), dx=h, axis=1) / p.period
    fbar = scipy.integrate.simpson(np.asarray(fs), dx=h, axis=1) / p.period
    np.testing.assert_allclose(r.x[1:], xbar[:-1], rtol=0, atol=1e-14)
    np.testing.assert_allclose(r.fh[1:], fbar[:-1], rtol=0, atol=1e-9 * np.abs(r.fh).max())
    np.testing.assert_array_equal(r.x[0], p.x0)
    np.testing.assert_array_equal(r.fh[0], 0.0)
    # ...and it differs from the instant samples by far more than that tolerance
    inst = aj.simulate(
        dataclasses.replace(p, acquisition="instant"),
        fd,
        numerics=aj.Numerics(solver=aj.solvers.RK4(), substeps=substeps),
    )
    assert np.abs(np.asarray(inst.fh) - np.asarray(r.fh)).max() > 1e-3 * np.abs(r.fh).max()


@pytest.mark.parametrize("controller", CONTROLLERS)
def test_any_two_batches_agree_bitwise_and_a_batch_equals_single_runs(sim, batch_sim, controller):
    """Any two batches (size >= 2) agree bitwise in everything (the same inputs give the same
    bits in another compilation and process: tests/test_determinism.py).

    A trial run alone is a scalar program to XLA, which FMA-contracts the sensor sums
    (``xd``, ``F_h``) differently from the vectorised one: the measured outputs differ by a
    few ulp, which IMBIC's feedback carries into the trajectory (seen: 3e-13 relative).
    """
    cases = [(0, 1, 0.25), (1, 2, 0.4), (2, 3, 0.25), (2, 4, 0.6)]
    params = [paper.trial(controller, f, loc, mhat=m * np.eye(2)) for f, loc, m in cases]
    fds = jnp.stack([_fd(400, seed=s) for s in range(len(cases))])
    singles = [sim(p, fd, substeps=5) for p, fd in zip(params, fds)]
    batch = batch_sim(aj.batch.stack_trials(params), fds, substeps=5)
    for i, single in enumerate(singles):
        row = jax.tree.map(lambda a, i=i: a[i], batch)
        assert int(row.diverged_at) == int(single.diverged_at) == -1
        for name in ("x", "q", "xd", "fh", "fu", "z"):
            a, b = np.asarray(getattr(row, name)), np.asarray(getattr(single, name))
            a, b = a - b[:1], b - b[:1]  # displacements, not the 0.4 m offset
            np.testing.assert_allclose(a, b, rtol=0, atol=1e-11 * np.abs(b).max())
    pair = batch_sim(aj.batch.stack_trials(params[1:3]), fds[1:3], substeps=5)
    assert tree_equal(pair, jax.tree.map(lambda a: a[1:3], batch))


def test_divergence_is_flagged_per_trial_without_poisoning_the_batch(sim, batch_sim):
    # mhat far above 2 M_x breaks time-delay estimation: the trial must blow up
    good = paper.trial("imbic", 0, 1)
    bad = paper.trial("imbic", 0, 1, mhat=20.0 * np.eye(2))
    fds = jnp.stack([_fd(400), _fd(400)])
    r = batch_sim(aj.batch.stack_trials([good, bad]), fds, substeps=5)
    assert not bool(r.diverged[0]) and int(r.diverged_at[0]) == -1
    assert bool(r.diverged[1]) and 0 < int(r.diverged_at[1]) < 400
    assert all(np.all(np.isfinite(leaf)) for leaf in jax.tree.leaves(r))
    k = int(r.diverged_at[1])
    np.testing.assert_array_equal(r.x[1, k:], np.broadcast_to(r.x[1, k - 1], r.x[1, k:].shape))
    alone = batch_sim(aj.batch.stack_trials([good, good]), fds, substeps=5)
    assert tree_equal(jax.tree.map(lambda a: a[0], r), jax.tree.map(lambda a: a[0], alone))


@pytest.mark.parametrize("friction_level", [0, pytest.param(2, marks=pytest.mark.slow)])
def test_gradient_wrt_mhat_is_finite(friction_level):
    fd = _fd(120)

    def loss(m):
        p = paper.trial("imbic", friction_level, 1, mhat=m)
        return jnp.sum(aj.simulate(p, fd, numerics=aj.Numerics(solver=aj.solvers.RK4(), substeps=4)).x ** 2)

    g = jax.grad(loss)(0.25 * jnp.eye(2))
    assert np.all(np.isfinite(g)) and np.any(g != 0)


def test_vmap_over_mhat_inside_trial_params(batch_sim):
    """trial_params accepts a traced mhat: vmapping over it equals stacking concrete params."""
    fd = _fd(100)

    def final_x(m):
        return aj.simulate(
            paper.trial("imbic", 1, 1, mhat=m), fd, numerics=aj.Numerics(solver=aj.solvers.RK4(), substeps=4)
        ).x[-1]

    ms = jnp.stack([0.25 * jnp.eye(2), 0.5 * jnp.eye(2)])
    out = jax.jit(jax.vmap(final_x))(ms)
    stacked = aj.batch.stack_trials([paper.trial("imbic", 1, 1, mhat=m) for m in ms])
    np.testing.assert_array_equal(out, batch_sim(stacked, jnp.stack([fd, fd]), substeps=4).x[:, -1])
    assert not np.array_equal(out[0], out[1])


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(controller="lqr"), "unknown controller 'lqr'; allowed: 'pd', 'imbic'"),
        (dict(friction_level=3), "unknown friction level 3; allowed: 0, 1, 2"),
        (dict(location=5), "unknown arm location 5; allowed: 1, 2, 3, 4"),
        (dict(mhat=np.eye(3)), r"IMBIC: mhat \[kg\] must be shape \(2, 2\), got shape \(3, 3\)"),
        (dict(mhat=-0.1 * np.eye(2)), "IMBIC: mhat must have a positive definite symmetric part"),
        (dict(mhat=np.zeros((2, 2))), "IMBIC: mhat must have a positive definite symmetric part"),
        (dict(mhat=np.array([[0.3, 0.0], [0.0, np.nan]])), r"IMBIC: mhat \[kg\] must be finite"),
        (dict(acquisition="oversampled"), "unknown acquisition 'oversampled'"),
        (dict(accel_estimate="kalman"), "unknown accel_estimate 'kalman'"),
    ],
)
def test_bad_paper_presets_are_rejected(kwargs, message):
    args = dict(controller="imbic", friction_level=1, location=1) | kwargs
    with pytest.raises(ValueError, match=message):
        paper.trial(args.pop("controller"), args.pop("friction_level"), args.pop("location"), **args)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(substeps=0), "substeps .* must be >= 1, got 0"),
        (dict(substeps=2.5), "substeps .* must be an integer >= 1, got 2.5"),
        (dict(solver="rk4"), r"solver must be RK4\(...\), ARK3\(...\), ARK4\(...\) or GradedARK4\(...\), got 'rk4'"),
        (dict(checkpoint="step"), "unknown checkpoint 'step'; allowed: 'period', 'substep'"),
    ],
)
def test_bad_numerics_are_rejected(kwargs, message):
    with pytest.raises(ValueError, match=message):
        aj.Numerics(**kwargs)


def test_bad_perturbation_and_batches_are_rejected():
    p = paper.trial("pd", 0, 1)
    with pytest.raises(ValueError, match=r"f_delta must have shape \(N, 2\)"):
        aj.simulate(p, jnp.zeros((10, 3)))
    with pytest.raises(ValueError, match=r"f_delta must have shape \(N, 2\)"):
        aj.simulate(p, jnp.zeros(10))
    with pytest.raises(ValueError, match="f_delta must be float64, got dtype float32"):
        aj.simulate(p, np.zeros((10, 2), dtype=np.float32))
    with pytest.raises(ValueError, match="must share the controller type"):
        aj.batch.stack_trials([p, paper.trial("imbic", 0, 1)])
    batch = aj.batch.stack_trials([p])
    with pytest.raises(ValueError, match=r"f_delta must have shape \(B, N, 2\), got \(1, 10\)"):
        sweep.simulate_batch(batch, np.zeros((1, 10)))
    for chunk in (None, 5):
        with pytest.raises(ValueError, match=r"at least one sample per trial, got shape \(1, 0, 2\)"):
            sweep.simulate_batch(batch, np.zeros((1, 0, 2)), chunk_samples=chunk)


def test_float32_mode_is_refused():
    jax.config.update("jax_enable_x64", False)
    try:
        with pytest.raises(ValueError, match="needs float64, but jax_enable_x64 is off"):
            paper.trial("pd", 0, 1)
    finally:
        jax.config.update("jax_enable_x64", True)


def test_a_missing_key_is_a_plain_error():
    """``aj.perturbation(0, ...)``: a line that says a key is needed, not JAX's key-data error."""
    with pytest.raises(ValueError, match=r"key must be a jax.random key \(e.g. jax.random.key\(0\)\), got int 0"):
        aj.perturbation(0, 100, 1.0)
    legacy = np.asarray(aj.perturbation(jax.random.PRNGKey(0), 50, 1.0))
    assert legacy.shape == (50, 2) and np.all(np.isfinite(legacy))
