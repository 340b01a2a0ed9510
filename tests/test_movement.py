"""The arm during a movement (docs/model.md, "The arm during a movement"): ``Profile`` and
``MinimumJerk`` against their closed forms, a still arm bitwise as before arms could move, the
moving plant against an independent SciPy reference, the paper's numerics against finer ones,
the planned path followed by every controller, ``jax.grad`` and ``vmap``, and refusals."""

import pathlib
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.integrate
from helpers import tree_equal

import armimp_jax as aj
from armimp_bench import movement as base
from armimp_jax import presets
from armimp_jax._model.movement import path_at, path_terms, profile_at, profile_terms

REFERENCE = pathlib.Path(__file__).with_name("data") / "still_reference.npz"
CONTROLLERS = {"pd": aj.PD, "imbic": aj.IMBIC, "admittance": aj.Admittance}
PAPER = aj.Numerics(solver=aj.solvers.RK4(), substeps=100)


@jax.jit(static_argnames="numerics")
def _sim(trial, fd, key=None, numerics=PAPER):
    return aj.simulate(trial, fd, key=key, numerics=numerics)


def _short_arm(location=3, dip=0.4, reach=(0.0, 0.05)):
    """A short reach (0.1 s onset, 0.2 s long) with K dipping at mid-reach: quick to simulate."""
    still = presets.arm(location)
    start = np.asarray(still.endpoint)
    path = aj.MinimumJerk(start=start, end=start + np.asarray(reach), onset=0.1, duration=0.2)
    k = aj.Profile(times=[0.1, 0.2, 0.3], values=np.asarray([1.0, dip, 1.0])[:, None, None] * still.stiffness)
    return aj.Arm(mass=still.mass, damping=still.damping, stiffness=k, endpoint=path)


# --- Profile and MinimumJerk ---------------------------------------------------------------


def test_profile_is_piecewise_linear_between_its_knots_and_constant_outside():
    times = np.array([0.2, 0.5, 0.6, 1.1])
    values = np.random.default_rng(0).normal(size=(4, 2, 2))
    p = aj.Profile(times=times, values=values)
    t = np.array([-1.0, 0.0, 0.2, 0.31, 0.5, 0.55, 0.6, 0.9, 1.1, 3.0])
    got = np.asarray(p(t))
    for i in range(2):
        for j in range(2):  # the closed form: linear between neighbouring knots, held outside
            np.testing.assert_allclose(got[:, i, j], np.interp(t, times, values[:, i, j]), rtol=0, atol=1e-15)
    terms = profile_terms(p)  # the plant's form of it, evaluated one time at a time
    for tk, want in zip(t, got):
        np.testing.assert_allclose(np.reshape(profile_at(terms, tk), (2, 2)), want, rtol=0, atol=1e-15)


def test_a_one_knot_profile_is_its_constant_matrix():
    still = presets.arm(3)
    arm = aj.Arm(
        mass=still.mass,
        damping=aj.Profile(times=[0.3], values=still.damping[None]),
        stiffness=aj.Profile(times=[0.7], values=still.stiffness[None]),
        endpoint=still.endpoint,
    )
    assert not arm.moving
    assert tree_equal(arm, still)


def test_minimum_jerk_matches_its_closed_form_and_its_velocity_the_derivative():
    a, b, onset, duration = np.array([-0.3, 0.3]), np.array([-0.25, 0.42]), 0.4, 0.8
    path = aj.MinimumJerk(start=a, end=b, onset=onset, duration=duration)
    t = np.linspace(0.0, 1.6, 321)
    s = np.clip((t - onset) / duration, 0, 1)[:, None]
    np.testing.assert_allclose(path.position(t), a + (b - a) * (10 * s**3 - 15 * s**4 + 6 * s**5), rtol=0, atol=1e-15)
    h = 1e-6
    fd = (np.asarray(path.position(t + h)) - np.asarray(path.position(t - h))) / (2 * h)
    np.testing.assert_allclose(path.velocity(t), fd, rtol=0, atol=1e-8)  # |v| up to 0.28 m/s
    peak = np.asarray(path.velocity(onset + duration / 2))  # 15/8 of the mean speed at mid-reach
    np.testing.assert_allclose(peak, 1.875 * (b - a) / duration, rtol=1e-14)
    np.testing.assert_array_equal(path.position(0.1), a)
    np.testing.assert_array_equal(path.velocity(0.1), 0.0)
    terms = path_terms(path)
    for tk in t[::20]:
        offset, velocity = path_at(terms, tk)
        np.testing.assert_allclose(np.asarray(offset) + a, path.position(tk), rtol=0, atol=1e-15)
        np.testing.assert_allclose(velocity, path.velocity(tk), rtol=0, atol=1e-15)


# --- a still arm runs the code it always ran -----------------------------------------------


def _reference():
    data = np.load(REFERENCE)
    if str(data["jax_version"]) != jax.__version__:
        pytest.skip(f"the still reference was made under JAX {data['jax_version']}, this is {jax.__version__}")
    return data


def _still_cases():
    """``tests/data/still_reference.py`` as a module (its cases; its set-up runs only as a script)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("still_reference", REFERENCE.with_suffix(".py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


# The default numerics for every controller and the paper's RK4 under PD in the default tier; the
# other eight pairs (2-5 s each, cold) in the slow tier, for the suite's 10-minute budget.
_DEFAULT_PAIRS = {("admittance", "gark4"), ("imbic", "gark4"), ("pd", "gark4"), ("pd", "rk4")}


@pytest.mark.parametrize(
    "controller, numerics",
    [
        pytest.param(c, n, marks=() if (c, n) in _DEFAULT_PAIRS else pytest.mark.slow)
        for c in sorted(CONTROLLERS)
        for n in ("rk4", "rk4ref", "ark3", "gark4")
    ],
)
def test_a_still_arm_is_bitwise_as_before_arms_could_move(controller, numerics):
    """``tests/data/still_reference.npz``: made by ``still_reference.py`` under commit d0a3dee's
    package (friction, sensor noise, the person's force; every solver)."""
    data = _reference()
    trial, f, key, num = _still_cases().case(controller, numerics)
    sim = _sim(trial, f, key=key, numerics=num)
    for field in ("x", "xd", "fh", "fu", "q", "z"):
        np.testing.assert_array_equal(np.asarray(getattr(sim, field)), data[f"{controller}.{numerics}.{field}"])


def test_a_reach_of_no_length_and_flat_profiles_is_the_still_arm_to_round_off():
    """A moving arm's program (a path, profiles of several knots) that describes a still arm gives
    the still arm's result but for round-off (measured: 3e-13 N): its F_h is summed in another order."""
    case = _still_cases().case("imbic", "rk4")
    trial, f, key, num = case
    still = trial.arm
    p = np.asarray(still.endpoint)
    flat = aj.Profile(times=[0.1, 0.2], values=np.stack([still.stiffness] * 2))
    path = aj.MinimumJerk(start=p, end=p, onset=0.05, duration=0.1)
    moving = aj.Arm(mass=still.mass, damping=still.damping, stiffness=flat, endpoint=path)
    assert moving.moving
    friction, sensors, voluntary = trial.friction, trial.sensors, trial.voluntary
    other = aj.make_trial(aj.IMBIC(), arm=moving, friction=friction, sensors=sensors, voluntary=voluntary)
    a, b = _sim(trial, f, key=key, numerics=num), _sim(other, f, key=key, numerics=num)
    np.testing.assert_array_equal(a.q, b.q)
    np.testing.assert_allclose(b.fh, a.fh, rtol=0, atol=1e-11)
    np.testing.assert_allclose(b.fu, a.fu, rtol=0, atol=1e-11)


# --- the moving plant against an independent reference -------------------------------------


def _reference_pd(arm: aj.Arm, robot: aj.Robot, q0, kp, kv, f_delta, period=1e-3):
    """The moving arm under PD without friction, from docs/model.md sections 3, 5, 7 and 19
    alone: NumPy, SciPy's DOP853 over each control period, from rest at ``q0`` [rad] (the path's
    start's inverse kinematics). Returns ``x`` and ``F_h`` ``(N, 2)``."""
    ls, le = float(robot.shoulder_link), float(robot.elbow_link)
    c1, c2, c3 = np.asarray(robot.inertia)
    base = np.asarray(robot.base)
    mh = np.asarray(arm.mass)
    path = arm.endpoint
    times_b, bs = np.asarray(arm.damping.times), np.asarray(arm.damping.values)
    times_k, ks = np.asarray(arm.stiffness.times), np.asarray(arm.stiffness.values)

    def interp(t, times, values):
        return np.array([[np.interp(t, times, values[:, i, j]) for j in range(2)] for i in range(2)])

    def kinematics(q, qd):
        s1, co1, s2, co2 = np.sin(q[0]), np.cos(q[0]), np.sin(q[1]), np.cos(q[1])
        x = base + np.array([ls * co1 + le * co2, ls * s1 + le * s2])
        jac = np.array([[-ls * s1, -le * s2], [ls * co1, le * co2]])
        jdqd = np.array([-ls * co1 * qd[0] ** 2 - le * co2 * qd[1] ** 2, -ls * s1 * qd[0] ** 2 - le * s2 * qd[1] ** 2])
        return x, jac, jdqd

    def accel(t, y, fu):
        q, qd = y[:2], y[2:]
        x, jac, jdqd = kinematics(q, qd)
        xe, xde = np.asarray(path.position(t)), np.asarray(path.velocity(t))
        spring = interp(t, times_b, bs) @ (jac @ qd - xde) + interp(t, times_k, ks) @ (x - xe)
        d = q[0] - q[1]
        m = np.array([[c1, c2 * np.cos(d)], [c2 * np.cos(d), c3]])
        h = np.array([c2 * np.sin(d) * qd[1] ** 2, -c2 * np.sin(d) * qd[0] ** 2])
        qdd = np.linalg.solve(m + jac.T @ mh @ jac, jac.T @ (fu - mh @ jdqd - spring) - h)
        return qdd, x, jac @ qd, mh @ (jac @ qdd + jdqd) + spring

    y, fu, xs, fhs = np.concatenate([np.asarray(q0), [0.0, 0.0]]), np.zeros(2), [], []
    for k, fd in enumerate(np.asarray(f_delta)):
        t = k * period
        _, x, xd, fh = accel(t, y, fu)
        xs.append(x)
        fhs.append(fh)
        fu = fd - kp @ (x - np.asarray(path.position(t))) - kv @ (xd - np.asarray(path.velocity(t)))
        sol = scipy.integrate.solve_ivp(
            lambda t, y: np.concatenate([y[2:], accel(t, y, fu)[0]]),
            (t, t + period),
            y,
            method="DOP853",
            rtol=1e-13,
            atol=1e-15,
        )
        y = sol.y[:, -1]
    return np.array(xs), np.array(fhs)


def test_the_moving_plant_under_pd_matches_an_independent_reference():
    """Both profiles move, the equilibrium reaches: the simulator at the paper's numerics against
    ``_reference_pd`` (an ODE solver at 1e-13) within 1e-11 of each signal's perturbed range
    (measured: 3e-13 and 2e-13)."""
    still = presets.arm(3)
    arm = _short_arm()
    damping = aj.Profile(times=[0.15, 0.25], values=np.stack([still.damping, 0.5 * still.damping]))
    arm = aj.Arm(mass=arm.mass, damping=damping, stiffness=arm.stiffness, endpoint=arm.endpoint)
    pd = aj.PD()
    trial = aj.make_trial(pd, arm=arm, friction=aj.NO_FRICTION)
    f = aj.perturbation(jax.random.PRNGKey(2), 400, 2.25)
    sim = _sim(trial, f)
    x, fh = _reference_pd(arm, aj.presets.MIT_MANUS, trial.q0, np.asarray(pd.kp), np.asarray(pd.kv), f)
    moved = np.asarray(sim.x) - np.asarray(arm.endpoint.position(np.arange(400) * 1e-3))
    np.testing.assert_allclose(sim.x, x, rtol=0, atol=1e-11 * np.ptp(moved))
    np.testing.assert_allclose(sim.fh, fh, rtol=0, atol=1e-11 * np.ptp(fh))
    assert np.ptp(moved) > 1e-3  # the perturbation moved the hand off its path


# --- the base case: the paper's numerics against finer ones ------------------------


def _fidelity(controller, friction, numerics):
    """The base case (``armimp_bench.movement``: paper arm 3, 12 cm in 0.8 s, K dipping to 40%, the still
    studies' noise) at ``numerics`` and at RK4 with 400 substeps: the largest differences of the
    true joint angles and of the recorded F_h, each over its range over the record."""
    trial = base.base_trial(controller, friction)
    n = int(round(base.RECORD / trial.period))
    f = aj.perturbation(jax.random.PRNGKey(5), n, base.PEAK)
    key = jax.random.PRNGKey(9)
    a = _sim(trial, f, key=key, numerics=numerics)
    b = _sim(trial, f, key=key, numerics=aj.Numerics(solver=aj.solvers.RK4(), substeps=400))
    assert not a.diverged and not b.diverged
    q = np.max(np.abs(np.asarray(a.q) - b.q)) / np.ptp(np.asarray(b.q), axis=0).min()
    fh = np.max(np.abs(np.asarray(a.fh) - b.fh)) / np.ptp(np.asarray(b.fh))
    return q, fh


@pytest.mark.slow  # 13 s cold: the suite's 10-minute budget
def test_the_base_reach_at_the_papers_numerics_is_within_1e7_and_the_default_within_1e3():
    """PD, no friction (measured: 3e-13 and 8e-13 at RK4/100; 3e-8 and 4e-8 by default)."""
    assert max(_fidelity(aj.PD(), aj.NO_FRICTION, PAPER)) < 1e-7
    assert max(_fidelity(aj.PD(), aj.NO_FRICTION, aj.Numerics())) < 1e-3


@pytest.mark.slow
@pytest.mark.parametrize("controller", ["imbic", "admittance"])
def test_the_base_reach_under_the_other_controllers(controller):
    """As the PD test, for IMBIC and admittance without friction."""
    c = CONTROLLERS[controller]()
    assert max(_fidelity(c, aj.NO_FRICTION, PAPER)) < 1e-7
    assert max(_fidelity(c, aj.NO_FRICTION, aj.Numerics())) < 1e-3


# --- the controllers follow the planned path -----------------------------------------------


@pytest.mark.parametrize("controller", sorted(CONTROLLERS))
def test_every_controller_follows_the_planned_path(controller):
    """Unperturbed and noise-free, the hand reaches with its equilibrium and comes to rest at the
    path's end, within a millimetre (the robot expects the reach). A robot that held the start
    instead would stop the hand centimetres short: its spring and the arm's would share the 5 cm.
    The arm's damping is raised to 25 N s/m on each axis so that it settles within the record
    (paper arm 3's own has a lightly damped mode that still swings by millimetres a second after
    the reach)."""
    arm = _short_arm()
    arm = aj.Arm(mass=arm.mass, damping=25.0 * np.eye(2), stiffness=arm.stiffness, endpoint=arm.endpoint)
    trial = aj.make_trial(CONTROLLERS[controller](), arm=arm, friction=aj.NO_FRICTION)
    sim = _sim(trial, jnp.zeros((1300, 2)), numerics=aj.Numerics(solver=aj.solvers.RK4(), substeps=20))
    assert not sim.diverged
    np.testing.assert_array_equal(sim.x[0], trial.x0)
    np.testing.assert_allclose(sim.x[-1], arm.endpoint.end, rtol=0, atol=1e-3)  # measured: 0.1-0.25 mm


# --- jax.grad, vmap, batches ---------------------------------------------------------------

SHORT = aj.Numerics(solver=aj.solvers.RK4(), substeps=10)


def _force_energy(dip, onset, f):
    """``sum F_h^2`` of the short reach under PD, as a function of K's mid-reach share and the onset."""
    still = presets.arm(3)
    start = np.asarray(still.endpoint)
    path = aj.MinimumJerk(start=start, end=start + np.array([0.0, 0.05]), onset=onset, duration=0.2)
    scale = jnp.stack([1.0, dip, 1.0])[:, None, None]
    k = aj.Profile(times=jnp.asarray([0.1, 0.2, 0.3]), values=scale * jnp.asarray(still.stiffness)[None])
    arm = aj.Arm(mass=still.mass, damping=still.damping, stiffness=k, endpoint=path)
    trial = aj.make_trial(aj.PD(), arm=arm, friction=aj.NO_FRICTION)
    return jnp.sum(aj.simulate(trial, f, numerics=SHORT).fh ** 2)


@pytest.mark.slow  # 9 s cold: the suite's 10-minute budget
def test_grad_through_a_profile_and_a_path_matches_finite_differences():
    f = aj.perturbation(jax.random.PRNGKey(4), 400, 2.25)
    grad = jax.jit(jax.grad(_force_energy, argnums=(0, 1)))(0.4, 0.1, f)
    energy = jax.jit(_force_energy)
    for i, h in enumerate((1e-4, 1e-5)):
        point = [0.4, 0.1]
        up, down = list(point), list(point)
        up[i] += h
        down[i] -= h
        fd = (energy(*up, f) - energy(*down, f)) / (2 * h)
        np.testing.assert_allclose(grad[i], fd, rtol=1e-5)
        assert abs(float(grad[i])) > 0


@pytest.mark.slow  # 10 s cold: the suite's 10-minute budget
def test_vmap_over_moving_arms_and_simulate_batch_agree_with_single_runs():
    arms = [_short_arm(dip=d) for d in (0.4, 0.8)]
    trials = [aj.make_trial(aj.IMBIC(), arm=a, friction=aj.NO_FRICTION) for a in arms]
    f = jnp.stack([aj.perturbation(jax.random.PRNGKey(s), 300, 2.25) for s in (1, 2)])
    singles = [_sim(t, fi, numerics=SHORT) for t, fi in zip(trials, f)]
    stacked = jax.tree.map(lambda *a: jnp.stack(a), *arms)
    batch = jax.jit(
        jax.vmap(
            lambda arm, fi: aj.simulate(aj.make_trial(aj.IMBIC(), arm=arm, friction=aj.NO_FRICTION), fi, numerics=SHORT)
        )
    )(stacked, f)
    sweep = aj.simulate_batch(aj.batch.stack_trials(trials), f, numerics=SHORT)
    for i, single in enumerate(singles):
        for out in (batch, sweep):
            np.testing.assert_allclose(out.fh[i], single.fh, rtol=0, atol=1e-10 * np.ptp(single.fh))
            np.testing.assert_allclose(out.x[i], single.x, rtol=0, atol=1e-12)
    assert np.ptp(np.asarray(singles[0].fh) - singles[1].fh) > 0.1  # the dip changes the force


# --- refusals, in one line, before any simulation ------------------------------------------


class _StillOnly(aj.AbstractController):
    """A damper whose step takes no planned path: it serves still arms only."""

    kind: ClassVar[str] = "toy_still_only"
    UNITS: ClassVar[dict] = {}
    DESIGN_GAINS: ClassVar[None] = None
    d: np.ndarray = eqx.field(converter=np.asarray, default=20.0)

    def init(self, x0):
        return ()

    def step(self, memory, x, xd, fh, f_delta, x0, period):
        return f_delta - self.d * xd, memory


def test_bad_profiles_and_paths_are_refused_in_one_line():
    k = presets.arm(3).stiffness
    with pytest.raises(ValueError, match=r"knot times must increase strictly, got \[0.1, 0.3, 0.2\] s \(knot 2"):
        aj.Profile(times=[0.1, 0.3, 0.2], values=np.stack([k] * 3))
    with pytest.raises(ValueError, match=r"values must have shape \(J, 2, 2\) = \(3, 2, 2\).*got shape \(2, 2, 2\)"):
        aj.Profile(times=[0.1, 0.2, 0.3], values=np.stack([k] * 2))
    with pytest.raises(ValueError, match=r"values must have shape .* got shape \(3, 4\)"):
        aj.Profile(times=[0.1, 0.2, 0.3], values=np.ones((3, 4)))
    with pytest.raises(ValueError, match="mass stays constant during a movement"):
        aj.Arm(mass=aj.Profile(times=[0.1], values=k[None]), damping=k, stiffness=k, endpoint=[-0.3, 0.3])
    with pytest.raises(ValueError, match="duration must be > 0 s, got 0 s"):
        aj.MinimumJerk(start=[0.0, 0.4], end=[0.0, 0.5], onset=0.1, duration=0.0)
    with pytest.raises(ValueError, match="onset must be >= 0 s, got -0.1 s"):
        aj.MinimumJerk(start=[0.0, 0.4], end=[0.0, 0.5], onset=-0.1, duration=0.5)


def test_a_trial_the_moving_arm_cannot_have_is_refused_in_one_line():
    arm = _short_arm()
    far = _short_arm(reach=(0.0, -0.6))  # towards the shoulder, past the robot's reach
    with pytest.raises(ValueError, match=r"make_trial: the reach from .* passes outside the robot's workspace at"):
        aj.make_trial(aj.PD(), arm=far, friction=aj.NO_FRICTION)
    with pytest.raises(ValueError, match="a moving arm needs acquisition 'instant', got 'interval_mean'"):
        aj.make_trial(aj.PD(), arm=arm, friction=aj.NO_FRICTION, acquisition="interval_mean")
    with pytest.raises(ValueError, match="the controller _StillOnly cannot follow a moving arm"):
        aj.make_trial(_StillOnly(), arm=arm, friction=aj.NO_FRICTION)
    aj.make_trial(_StillOnly(), arm=presets.arm(3), friction=aj.NO_FRICTION)  # a still arm it serves
    with pytest.raises(ValueError, match="a moving arm has no single impedance; use arm.at"):
        arm.impedance(np.array([1.0]))
    still = aj.make_trial(aj.PD(), arm=presets.arm(3), friction=aj.NO_FRICTION)
    with pytest.raises(ValueError, match="trials in one batch must move alike"):
        aj.batch.stack_trials([still, aj.make_trial(aj.PD(), arm=arm, friction=aj.NO_FRICTION)])
