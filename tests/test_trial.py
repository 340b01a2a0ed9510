"""The general simulator's values: presets, custom scenarios, invariants, gradients, bad input."""

import pathlib
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import tree_equal, zoh_response

import armimp_jax as aj
from armimp_jax import paper
from armimp_jax._model.plant import PlantModel, PlantState, plant_derivative
from armimp_jax._model.robot import kinetic_energy
from armimp_jax._solver.rk4 import rk4_step


def _run(trials, fds, substeps, **kw):
    return jax.jit(
        jax.vmap(lambda t, f: aj.simulate(t, f, numerics=aj.Numerics(solver=aj.solvers.RK4(), substeps=substeps), **kw))
    )(trials, fds)


CUSTOM_ARM = aj.Arm(
    mass=[[1.2, -0.3], [-0.35, 0.8]],
    damping=[[9.0, -2.0], [-2.5, 6.0]],
    stiffness=[[180.0, -40.0], [-55.0, 120.0]],
    endpoint=[0.05, 0.36],
)


def test_custom_scenario_realises_the_desired_dynamics_it_asks_for():
    """Own arm at an own endpoint, own gains, own desired inertia and mhat: frictionless IMBIC
    makes robot + arm behave as (M_rd + M_h, B_rd + B_h, K_rd + K_h), solved independently."""
    m_rd = np.array([[1.6, 0.4], [0.4, 1.4]])
    ctrl = aj.IMBIC(mhat=[[0.3, 0.02], [0.02, 0.2]], kp=[[300.0, 20.0], [20.0, 200.0]], kv=[[6.0, 0.0], [0.0, 5.0]])
    ctrl = aj.IMBIC(mhat=ctrl.mhat, kp=ctrl.kp, kv=ctrl.kv, m_rd=m_rd)
    trial = aj.make_trial(ctrl, arm=CUSTOM_ARM, friction=aj.NO_FRICTION)
    fd = aj.perturbation(jax.random.PRNGKey(1), 2000, 2.0)
    e = np.asarray(
        jax.jit(aj.simulate, static_argnames="numerics")(
            trial, fd, numerics=aj.Numerics(solver=aj.solvers.RK4(), substeps=10)
        ).x
    )
    e = e - np.asarray(trial.x0)
    ref = zoh_response(m_rd + CUSTOM_ARM.mass, ctrl.kv + CUSTOM_ARM.damping, ctrl.kp + CUSTOM_ARM.stiffness, fd, 1e-3)
    rel = np.sqrt(np.mean((e - ref) ** 2) / np.mean(ref**2))
    assert rel < 0.02, rel
    wrong = zoh_response(
        0.5 * m_rd + CUSTOM_ARM.mass, ctrl.kv + CUSTOM_ARM.damping, ctrl.kp + CUSTOM_ARM.stiffness, fd, 1e-3
    )
    assert np.sqrt(np.mean((e - wrong) ** 2) / np.mean(wrong**2)) > 0.1
    np.testing.assert_allclose(trial.x0, CUSTOM_ARM.endpoint, atol=1e-15)


def test_custom_friction_is_per_joint_and_a_batch_mixes_everything():
    f1 = aj.LuGre(tau_c=[0.5, 2.0], tau_s=[0.8, 2.5], sigma2=[0.3, 0.7])
    np.testing.assert_array_equal(f1.tau_c, [0.5, 2.0])
    np.testing.assert_array_equal(f1.sigma0, [1e5, 1e5])
    trials = [
        aj.make_trial(aj.IMBIC(mhat=0.3 * np.eye(2)), arm=CUSTOM_ARM, friction=f1),
        aj.make_trial(aj.IMBIC(), arm=paper.arm(2), friction=paper.friction(2), robot=aj.Robot(shoulder_link=0.42)),
    ]
    fds = jnp.stack([aj.perturbation(jax.random.PRNGKey(i), 300, 2.0) for i in range(2)])
    batch = _run(aj.batch.stack_trials(trials), fds, 20)
    for i, t in enumerate(trials):
        alone = _run(aj.batch.stack_trials([t, t]), fds[i : i + 1].repeat(2, 0), 20)
        assert tree_equal(jax.tree.map(lambda a: a[i], batch), jax.tree.map(lambda a: a[0], alone))
    assert not np.any(batch.diverged)


@pytest.mark.parametrize("substeps", [1, 2, 4])
def test_free_robot_conserves_kinetic_energy_to_fourth_order(substeps):
    """No friction, no arm, no command: the linkage coasts, and RK4's energy error per step is
    O(h^5), so the drift over a fixed time falls 16x when h halves (jax-md style invariant)."""
    trial = paper.trial("pd", 0, 1)
    zero = (0.0, 0.0, 0.0, 0.0)
    nf = aj.NO_FRICTION
    model = PlantModel(tuple(trial.x0), (1.0, 0.0, 1.0, 0.0), zero, zero, zero, (nf.joint(0), nf.joint(1)), trial.robot)
    q0 = np.asarray(trial.q0)
    s0 = PlantState(q0[0], q0[1], jnp.asarray(3.0), jnp.asarray(-5.0), 0.0, 0.0, 0.0, 0.0)
    e0 = kinetic_energy(jnp.stack([s0.q1, s0.q2]), jnp.stack([s0.qd1, s0.qd2]), trial.robot)

    def drift(n):
        h = 0.2 / n

        def step(s, _):
            return rk4_step(s, jnp.zeros(2), model, h), None

        s = jax.lax.scan(step, s0, None, length=n)[0]
        return abs(float(kinetic_energy(jnp.stack([s.q1, s.q2]), jnp.stack([s.qd1, s.qd2]), trial.robot) - e0) / e0)

    d = [drift(25 * substeps * 2**k) for k in range(2)]
    assert d[0] < 1e-6
    ratio = d[0] / d[1]
    assert 12 < ratio < 20, (d, ratio)
    # the derivative itself conserves energy: dT/dt = qd . (M qdd + Md qd / 2) = 0 with no torque
    deriv = plant_derivative(s0, jnp.zeros(2), model)
    pw = jax.jvp(
        lambda q, qd: kinetic_energy(q, qd, trial.robot),
        (jnp.stack([s0.q1, s0.q2]), jnp.stack([s0.qd1, s0.qd2])),
        (jnp.stack([s0.qd1, s0.qd2]), jnp.stack([deriv.qd1, deriv.qd2])),
    )[1]
    assert abs(float(pw)) < 1e-12 * float(e0)


def _phi(trial, fd, numerics=aj.Numerics(solver=aj.solvers.RK4(), substeps=10)):
    sim = aj.simulate(trial, fd, numerics=numerics)
    est = aj.estimate(fd, sim.x, sim.fh, nperseg=512, noverlap=384)
    return aj.spectra.accuracy(est.Z, est.f, trial.arm)[0]


def _fd():
    return aj.perturbation(jax.random.PRNGKey(7), 1500, 2.25)


@pytest.mark.parametrize(
    "controller, name",
    [
        ("imbic", "mhat"),
        pytest.param("imbic", "kp", marks=pytest.mark.slow),
        pytest.param("pd", "kp", marks=pytest.mark.slow),
        # d phi_T / d tau_c is checked fast in test_ark.py (ARK3; test_graded.py's, Numerics(), is slow)
        pytest.param("pd", "tau_c", marks=pytest.mark.slow),
        pytest.param("pd", "sigma1", marks=pytest.mark.slow),
    ],
)
def test_gradients_of_phi_agree_with_central_differences(controller, name):
    """d phi_T / d(scale of a gain or LuGre parameter). IMBIC's gains are checked without
    friction: with friction its stick-slip makes phi_T rough at small scales (difference
    quotients wander by 1e-3 between steps of 1e-3 and 1e-5). Under PD, where the joints stay
    in pre-sliding, the quotients converge to the gradient as the step shrinks."""
    fd = _fd()
    arm = paper.arm(1)

    def build(x):
        gains = dict(kp=250.0 * jnp.eye(2) * (x if name == "kp" else 1.0))
        if controller == "imbic":
            ctrl = aj.IMBIC(mhat=0.3 * jnp.eye(2) * (x if name == "mhat" else 1.0), **gains)
            return aj.make_trial(ctrl, arm=arm, friction=aj.NO_FRICTION)
        lugre = dict(tau_c=0.5 * (x if name == "tau_c" else 1.0), tau_s=0.75)
        if name == "sigma1":
            lugre["sigma1"] = 316.0 * x
        return aj.make_trial(aj.PD(**gains), arm=arm, friction=aj.LuGre(**lugre))

    f = jax.jit(lambda x: _phi(build(x), fd))
    g = float(jax.jit(jax.grad(lambda x: _phi(build(x), fd)))(1.0))
    eps = 1e-5
    central = (float(f(1.0 + eps)) - float(f(1.0 - eps))) / (2 * eps)
    assert np.isfinite(g) and g != 0.0
    np.testing.assert_allclose(g, central, rtol=1e-4)


# --- sensors -------------------------------------------------------------------------------


def test_ideal_sensors_are_bitwise_ideal_and_pd_motion_ignores_force_noise():
    fd = jnp.stack([aj.perturbation(jax.random.PRNGKey(3), 600, 2.25)] * 2)
    keys = jax.random.split(jax.random.PRNGKey(0), 2)
    plain = aj.batch.stack_trials([paper.trial("pd", 1, 1)] * 2)
    off = aj.batch.stack_trials([paper.trial("pd", 1, 1, sensors=aj.Sensors(force_noise=0.0))] * 2)
    noisy = aj.batch.stack_trials([paper.trial("pd", 1, 1, sensors=aj.Sensors(force_noise=0.5))] * 2)
    a, b = _run(plain, fd, 5), _run(off, fd, 5, key=None)
    assert tree_equal(a, b)
    n = jax.jit(
        jax.vmap(lambda t, f, k: aj.simulate(t, f, key=k, numerics=aj.Numerics(solver=aj.solvers.RK4(), substeps=5)))
    )(noisy, fd, keys)
    for name in ("x", "xd", "fu", "q", "z"):  # PD does not read F_h
        assert tree_equal(getattr(n, name), getattr(a, name)), name
    noise = np.asarray(n.fh - a.fh)
    assert np.all(noise != 0)
    np.testing.assert_allclose(noise.std(axis=1), 0.5, rtol=0.1)  # 600 samples: ~3% scatter
    lag1 = np.mean(noise[:, 1:] * noise[:, :-1]) / np.mean(noise**2)
    assert abs(lag1) < 0.1  # white
    assert abs(np.corrcoef(noise[0, :, 0], noise[1, :, 0])[0, 1]) < 0.15  # independent keys
    # (the same key gives the same noise in another compilation and process: tests/test_determinism.py)


def test_encoder_quantisation_and_velocity_noise():
    counts = 4096
    sensors = aj.Sensors(encoder_counts=counts, velocity_noise=0.01)
    t = paper.trial("pd", 0, 1, sensors=sensors)
    fd = aj.perturbation(jax.random.PRNGKey(3), 400, 2.25)
    r = jax.jit(aj.simulate, static_argnames="numerics")(
        t, fd, key=jax.random.PRNGKey(1), numerics=aj.Numerics(solver=aj.solvers.RK4(), substeps=5)
    )
    # the recorded position is the forward kinematics of quantised angles
    step = 2 * np.pi / counts
    q_read = np.round(np.asarray(r.q) / step) * step
    from armimp_jax._model.robot import fk

    x_expected = np.stack([np.asarray(fk(jnp.asarray(q), t.robot)) for q in q_read[::50]])
    np.testing.assert_allclose(np.asarray(r.x)[::50], x_expected, atol=1e-12)
    steps_taken = np.unique(np.round(np.diff(np.asarray(r.x)[:, 0]), 12))
    assert len(steps_taken) < 20  # a handful of encoder steps, not a continuum
    ideal = jax.jit(aj.simulate, static_argnames="numerics")(
        paper.trial("pd", 0, 1), fd, numerics=aj.Numerics(solver=aj.solvers.RK4(), substeps=5)
    )
    assert not np.array_equal(np.asarray(r.xd), np.asarray(ideal.xd))


def test_noise_needs_a_key():
    t = paper.trial("pd", 0, 1, sensors=aj.Sensors(force_noise=0.1))
    with pytest.raises(ValueError, match="pass key="):
        aj.simulate(t, jnp.zeros((10, 2)))


# --- bad input -----------------------------------------------------------------------------

GOOD_ARM = dict(mass=np.eye(2), damping=np.eye(2), stiffness=100 * np.eye(2), endpoint=[-0.15, 0.39])


@pytest.mark.parametrize(
    "make, message",
    [
        (
            lambda: aj.Arm(**(GOOD_ARM | dict(mass=np.eye(3)))),
            r"Arm: mass \[kg\] must be shape \(2, 2\), got shape \(3, 3\)",
        ),
        (lambda: aj.Arm(**(GOOD_ARM | dict(endpoint=[0.1, 0.2, 0.3]))), r"Arm: endpoint \[m\] must be shape \(2,\)"),
        (lambda: aj.Arm(**(GOOD_ARM | dict(stiffness=[[1, np.inf], [0, 1]]))), "Arm: stiffness .* must be finite"),
        (
            lambda: aj.Arm(**(GOOD_ARM | dict(mass=-np.eye(2)))),
            "Arm: mass must have a positive semi-definite symmetric part",
        ),
        (lambda: aj.LuGre(-0.1, 0.2), r"LuGre: tau_c must be >= 0 N m, got \[-0.1, -0.1\]"),
        (lambda: aj.LuGre(1.0, 0.5), "LuGre: tau_s must be >= tau_c"),
        (lambda: aj.LuGre(1.0, 1.5, v_s=0.0), "LuGre: v_s must be > 0 rad/s"),
        (lambda: aj.LuGre(1.0, 1.5, sigma0=-1.0), "LuGre: sigma0 must be >= 0"),
        (lambda: aj.LuGre(1.0, 1.5, sigma2=[0.1, 0.2, 0.3]), r"LuGre: sigma2 .* must be a scalar or shape \(2,\)"),
        (lambda: aj.PD(kp=-np.eye(2)), "PD: kp must have a positive definite symmetric part"),
        (lambda: aj.PD(kv=[[1.0, 0.0], [0.0, np.nan]]), r"PD: kv \[N s/m\] must be finite"),
        (lambda: aj.IMBIC(mhat=[[0.0, 1.0], [-1.0, 0.0]]), "IMBIC: mhat must have a positive definite symmetric part"),
        (lambda: aj.IMBIC(accel_estimate="kalman"), "unknown accel_estimate 'kalman'"),
        (lambda: aj.Sensors(force_noise=-0.1), "Sensors: force_noise must be >= 0 N"),
        (lambda: aj.Sensors(velocity_noise=-1.0), "Sensors: velocity_noise must be >= 0 rad/s"),
        (lambda: aj.Sensors(encoder_counts=0.5), "Sensors: encoder_counts must be >= 1 counts per revolution"),
        (lambda: aj.Robot(shoulder_link=0.0), "Robot: shoulder_link must be > 0 m"),
        (lambda: aj.Robot(inertia=(0.1, 0.5, 0.1)), "Robot: inertia .* must give a positive definite M"),
        (
            lambda: aj.make_trial(
                aj.PD(), arm=aj.Arm(**(GOOD_ARM | dict(endpoint=[3.0, 3.0]))), friction=aj.NO_FRICTION
            ),
            "outside the robot's workspace",
        ),
        (
            lambda: aj.make_trial(
                aj.PD(), arm=aj.Arm(**(GOOD_ARM | dict(endpoint=[-0.1487, 1.0425 - 0.92]))), friction=aj.NO_FRICTION
            ),
            "too close to a singular posture",
        ),
        (lambda: aj.make_trial(aj.PD(), arm=paper.arm(1), friction=1.0), "friction must be an AbstractFriction"),
        (
            lambda: aj.make_trial("pd", arm=paper.arm(1), friction=aj.NO_FRICTION),
            "controller must be an AbstractController",
        ),
        (lambda: aj.make_trial(aj.PD(), arm=paper.arm(1), friction=aj.NO_FRICTION, period=0), "period must be"),
    ],
)
def test_bad_input_is_refused_with_the_value_and_the_allowed_range(make, message):
    with pytest.raises(ValueError, match=message):
        make()


def test_tracers_pass_the_checks_so_vmap_and_grad_flow():
    arms = jax.vmap(lambda k: aj.Arm(k * jnp.eye(2), jnp.eye(2), 100 * jnp.eye(2), jnp.array([-0.15, 0.39])))(
        jnp.array([1.0, 2.0])
    )
    assert arms.mass.shape == (2, 2, 2)
    g = jax.grad(lambda tc: aj.LuGre(tc, 2.0 * tc).tau_s.sum())(1.0)
    assert float(g) == 4.0


def test_an_arm_no_human_has_gets_one_line_with_its_likely_cause_and_the_robot_alone_none():
    """A mass typed in grams and a negative stiffness are warned of (not refused: Arm documents
    unstable and negative-stiffness arms as studies), each in one line naming the entry, the
    range and the likely cause; the README's arm, the paper's and no_arm (all zero) pass quietly."""
    m, b, k, end = (np.asarray(getattr(CUSTOM_ARM, n)) for n in ("mass", "damping", "stiffness", "endpoint"))
    grams = aj.Arm(1000.0 * m, b, k, end)
    with pytest.warns(UserWarning) as caught:
        aj.make_trial(aj.PD(), arm=grams, friction=aj.NO_FRICTION)
    (line,) = [str(w.message) for w in caught]
    assert line.startswith("make_trial: an arm no human has: mass[0,0] 1200 kg (over 10 kg), mass[1,1] 800 kg")
    assert "likely cause: units (a mass typed in grams" in line and "\n" not in line
    flipped = aj.Arm(m, b, k * np.array([[1.0, 1.0], [1.0, -1.0]]), end)
    with pytest.warns(UserWarning, match=r"stiffness\[1,1\] -120 N/m \(negative\); likely cause: a sign convention"):
        aj.make_trial(aj.IMBIC(), arm=flipped, friction=aj.NO_FRICTION)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for arm in (CUSTOM_ARM, paper.arm(1), aj.presets.no_arm(end)):
            aj.make_trial(aj.PD(), arm=arm, friction=aj.NO_FRICTION)


def test_the_sensors_schema_is_read_not_restated():
    # a Sensors field named in its schema reaches a config's [sensors], a sweep point (--set, the
    # table's columns) and identify's names with no other file touched
    from armimp_jax._identification import layout
    from armimp_jax._model import sensors
    from armimp_jax.study.schema import config, points

    assert list(config.TRIAL_SECTIONS["sensors"]) == list(sensors.SETTINGS)
    assert [k for k in points.POINT_DEFAULTS if k in sensors.SETTINGS] == list(sensors.SETTINGS)
    assert set(layout.SENSOR_PARAMETERS) == {f"sensors.{n}" for n in sensors.IDENTIFIABLE}
    for module in (config, points, layout):
        text = pathlib.Path(module.__file__).read_text()
        assert not [n for n in (*sensors.SETTINGS, *sensors.IDENTIFIABLE) if f'"{n}"' in text], module.__name__


def test_one_builder_of_a_trial_from_settings():
    # a config's sections and a sweep's point build through the one study.build_trial: the same
    # trial (leaf for leaf) from either; a flat point handed to it is refused in one line
    from armimp_jax import study
    from armimp_jax.study.schema.config import ConfigError

    sections = dict(
        controller=dict(type="imbic", mhat=[[0.5, 0.0], [0.0, 0.5]]),
        friction=dict(type="lugre", tau_c=0.5, tau_s=0.75),
        arm={n: np.asarray(getattr(paper.arm(2), n)).tolist() for n in ("mass", "damping", "stiffness", "endpoint")},
    )
    point = study.Point.parse(dict(controller="imbic", mhat=0.5, tau_c=0.5, arm=2))
    assert tree_equal(study.build_trial(sections), point.trial)
    flat = dict(controller="imbic", mhat=0.5, tau_c=0.5, arm=2)
    with pytest.raises(ConfigError, match=r"flat key\(s\) 'arm'.*study\.Point\.parse\(point\)\.trial") as e:
        study.build_trial(flat)
    assert "\n" not in str(e.value)
