"""A lab's protocol (issue 47): the force channel's calibration and a force from the motor torques
against closed forms written here, several recordings in one identification (postures, the
robot alone, repeated trials), and the bias a calibration error leaves."""

import dataclasses

import jax
import numpy as np
import pytest

import armimp_jax as aj
from armimp_jax import paper
from armimp_jax._model.robot import cartesian_inertia, jacobian

# Frictionless loops are not stiff: RK4 at 2 substeps (the suite is compile-bound).
NUM = aj.Numerics(solver=aj.solvers.RK4(), substeps=2)
F = aj.perturbation(jax.random.key(4), 2000, paper.perturbation_peak(1))
ARM = ("arm.mass", "arm.damping", "arm.stiffness")
F_POOL = F[:1024]  # identify's least record: the pooled test's compile, not its length, is the cost
NOISE = dict(sensors=aj.Sensors(force_noise=0.05, encoder_counts=2**18), voluntary=aj.VoluntaryForce(0.3, 2.0))


def _sim(trial, f=F, key=None):
    return jax.jit(aj.simulate, static_argnames="numerics")(trial, f, key=key, numerics=NUM)


def test_the_recorded_force_channel_has_its_gain_offset_and_delay():
    plain = aj.make_trial(aj.PD(), arm=paper.arm(2), friction=aj.NO_FRICTION)
    sensors = aj.Sensors(force_gain=[1.1, 0.9], force_offset=[0.2, -0.1], force_delay=0.0025)
    cal = aj.make_trial(aj.PD(), arm=paper.arm(2), friction=aj.NO_FRICTION, sensors=sensors)
    fh, fc = np.asarray(_sim(plain).fh), np.asarray(_sim(cal).fh)
    # 2.5 samples late: half of each neighbour; PD never reads the force, so the motion is the same
    want = np.array([1.1, 0.9]) * 0.5 * (fh[:-3] + fh[1:-2]) + np.array([0.2, -0.1])
    np.testing.assert_allclose(fc[3:], want, rtol=0, atol=1e-14)
    with pytest.raises(ValueError, match="force_delay must be below 0.007 s"):
        aj.make_trial(aj.PD(), arm=paper.arm(2), friction=aj.NO_FRICTION, sensors=aj.Sensors(force_delay=0.01))


def test_a_force_from_the_motor_torques_is_the_command_less_the_models_inertial_force():
    model = aj.Robot(inertia=1.1 * np.asarray(aj.presets.MIT_MANUS.inertia))  # the lab's model, 10% off
    trial = aj.make_trial(aj.IMBIC(), arm=paper.arm(2), friction=aj.NO_FRICTION, sensors=aj.Sensors(force_model=model))
    sim = _sim(trial)
    fu, xd, q = (np.asarray(a) for a in (sim.fu, sim.xd, sim.q))
    inertia = np.asarray(jax.vmap(lambda qq: cartesian_inertia(qq, model))(q[1:]))
    want = fu[:-1] - np.einsum("kij,kj->ki", inertia, (xd[1:] - xd[:-1]) / trial.period)
    np.testing.assert_allclose(np.asarray(sim.fh)[1:], want, rtol=1e-12, atol=1e-12)


def test_a_motor_force_less_the_labs_friction_law_is_the_closed_form():
    # a static law in the plant and the same law subtracted: F_u - M_x a - J^-T tau_f(qd), qd = J^-1 xd
    law = aj.CoulombViscous(0.3, 0.5, v_s=0.01)
    sensors = aj.Sensors(force_model=aj.presets.MIT_MANUS, force_friction=law)
    trial = aj.make_trial(aj.IMBIC(), arm=paper.arm(2), friction=law, sensors=sensors)
    sim = jax.jit(aj.simulate, static_argnames="numerics")(trial, F, numerics=aj.Numerics(substeps=4))
    fu, xd, q = (np.asarray(a) for a in (sim.fu, sim.xd, sim.q))
    jac = np.asarray(jax.vmap(jacobian)(q[1:]))
    inertia = np.asarray(jax.vmap(cartesian_inertia)(q[1:]))
    qd = np.linalg.solve(jac, xd[1:, :, None])[..., 0]
    tau = 0.3 * np.tanh(qd / 0.01) + 0.5 * qd
    want = fu[:-1] - np.einsum("kij,kj->ki", inertia, (xd[1:] - xd[:-1]) / trial.period)
    want = want - np.linalg.solve(np.swapaxes(jac, 1, 2), tau[..., None])[..., 0]
    np.testing.assert_allclose(np.asarray(sim.fh)[1:], want, rtol=1e-9, atol=1e-9)


def test_imbic_cancels_the_friction_through_a_motor_force_only_once_the_lab_subtracts_it():
    """Without a transducer IMBIC reads the friction as the person's force and its joints stick
    (as PD's); with the lab's static law subtracted they move as with a transducer."""
    from armimp_jax._identification.diagnosis import motion_diagnosis

    lugre = aj.LuGre(0.5, 0.75)
    f = aj.perturbation(jax.random.key(7), 4000, paper.perturbation_peak(1))
    robot = aj.presets.MIT_MANUS
    cases = dict(
        transducer=aj.Sensors(),
        motor=aj.Sensors(force_model=robot),
        subtracted=aj.Sensors(force_model=robot, force_friction=aj.CoulombViscous(0.5, lugre.sigma2, v_s=1e-3)),
    )
    stuck = {}
    for name, sensors in cases.items():
        trial = aj.make_trial(aj.IMBIC(), arm=paper.arm(2), friction=lugre, sensors=sensors)
        x = jax.jit(aj.simulate, static_argnames="numerics")(trial, f, numerics=aj.Numerics()).x
        stuck[name] = float(np.max(motion_diagnosis(trial, x).fraction))
    assert stuck["motor"] > 0.5 and stuck["transducer"] < 0.15 and stuck["subtracted"] < 0.15, stuck


def test_a_subtracted_friction_law_is_refused_in_one_line_where_it_cannot_be():
    robot, law = aj.presets.MIT_MANUS, aj.CoulombViscous(0.5, 1.0, v_s=1e-3)
    cases = [
        (dict(force_friction=law), r"^Sensors: force_friction CoulombViscous is subtracted from the motor torques: "),
        (
            dict(force_model=robot, force_friction=aj.LuGre(0.5, 0.75)),
            r"must be a static law \(no bristle state\), got LuGre",
        ),
        (
            dict(force_model=robot, force_friction=0.5),
            r"force_friction must be a friction law \(CoulombViscous, say\), got 0.5",
        ),
    ]
    for kwargs, message in cases:
        with pytest.raises(ValueError, match=message) as e:
            aj.Sensors(**kwargs)
        assert "\n" not in str(e.value)
    # a batch reads its hand force one way: one line naming each trial's reading
    plain = aj.make_trial(aj.IMBIC(), arm=paper.arm(2), friction=aj.NO_FRICTION)
    motor = dataclasses.replace(plain, sensors=aj.Sensors(force_model=robot, force_friction=law))
    with pytest.raises(ValueError, match=r"the hand force's reading; got .*'motor less a law'.*'transducer'"):
        aj.batch.stack_trials([plain, motor])


def test_a_noise_free_check_reads_the_force_as_the_trial_does():
    # the loop check (crlb's, identify's choice of statistic) compares the noise-free simulation with
    # the linearised loop: both read the motor force, so a heavy model robot is no nonlinearity
    from armimp_jax._identification.bound import nonlinearity

    model = aj.Robot(inertia=1.15 * np.asarray(aj.presets.MIT_MANUS.inertia))
    sensors = aj.Sensors(force_model=model, force_friction=aj.CoulombViscous(0.0, 0.25))
    trial = aj.make_trial(aj.IMBIC(), arm=paper.arm(2), friction=aj.CoulombViscous(0.0, 0.5), sensors=sensors)
    assert np.max(nonlinearity(trial, F[:2000])) < 1e-2


@pytest.mark.slow  # 50 s cold: the pooled layout's compile (the suite's 10-minute budget)
def test_two_postures_in_one_identification_share_the_robot_and_keep_their_own_arms():
    """Noise-free: each posture's stiffness its own, the robot's inertia (15% off the model's)
    one value for both, every entry the truth; one joint covariance over all of them."""
    truth_robot = aj.Robot(inertia=1.15 * np.asarray(aj.presets.MIT_MANUS.inertia))
    recordings = []
    for loc in (1, 2):
        arm = paper.arm(loc)
        sim = _sim(aj.make_trial(aj.PD(), arm=arm, friction=aj.NO_FRICTION, robot=truth_robot), F_POOL)
        start = aj.Arm(arm.mass, arm.damping, 0.9 * arm.stiffness, arm.endpoint)
        model = aj.make_trial(aj.PD(), arm=start, friction=aj.NO_FRICTION)
        recordings.append(aj.Recording(model, F_POOL, sim.x, sim.fh, group=str(loc)))
    res = aj.identify(recordings, free=("arm.stiffness", "robot.inertia"), numerics=NUM, draws=8, jacobian_draws=2)
    assert res.converged, res.message
    assert set(res.values) == {"arm.stiffness@1", "arm.stiffness@2", "robot.inertia"}
    for loc in (1, 2):
        np.testing.assert_allclose(res.values[f"arm.stiffness@{loc}"], paper.arm(loc).stiffness, rtol=1e-6)
    np.testing.assert_allclose(res.values["robot.inertia"], truth_robot.inertia, rtol=1e-6)
    assert np.asarray(res.covariance).shape == (11, 11) and [r.group for r in res.recordings] == ["1", "2"]


@pytest.mark.slow  # about 70 s cold: three templates, two layouts (the script's own: test_identify_pool.py, slow)
def test_postures_and_the_robot_alone_in_one_identification_recover_every_parameter():
    """Noise-free: two postures and a robot-alone recording, the robot's inertia shared."""
    truth_robot = aj.Robot(inertia=1.15 * np.asarray(aj.presets.MIT_MANUS.inertia))
    recordings = []
    for loc, arm in ((1, paper.arm(1)), (2, paper.arm(2)), ("alone", aj.presets.no_arm(paper.location_endpoint(2)))):
        truth = aj.make_trial(aj.PD(), arm=arm, friction=aj.NO_FRICTION, robot=truth_robot)
        sim = _sim(truth)
        start_arm = arm if loc == "alone" else aj.Arm(1.1 * arm.mass, arm.damping, 0.9 * arm.stiffness, arm.endpoint)
        model = aj.make_trial(aj.PD(), arm=start_arm, friction=aj.NO_FRICTION)
        recordings.append(aj.Recording(model, F, sim.x, sim.fh, group=str(loc)))
    res = aj.identify(
        recordings, free=("arm.mass", "arm.stiffness", "robot.inertia"), numerics=NUM, draws=8, jacobian_draws=2
    )
    assert res.converged, res.message
    assert set(res.values) == {"arm.mass@1", "arm.stiffness@1", "arm.mass@2", "arm.stiffness@2", "robot.inertia"}
    for loc in (1, 2):
        np.testing.assert_allclose(res.values[f"arm.stiffness@{loc}"], paper.arm(loc).stiffness, rtol=1e-6)
        np.testing.assert_allclose(res.values[f"arm.mass@{loc}"], paper.arm(loc).mass, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(res.values["robot.inertia"], truth_robot.inertia, rtol=1e-6)
    assert [r.group for r in res.recordings] == ["1", "2", "alone"]


@pytest.mark.slow  # about 50 s cold: two identifications at 16 draws
def test_repeated_trials_share_one_binding_and_halve_the_variance():
    truth = aj.make_trial(aj.PD(), arm=paper.arm(2), friction=aj.NO_FRICTION, **NOISE)
    sims = [_sim(truth, key=jax.random.key(10 + i)) for i in range(2)]
    kw = dict(free=("arm.stiffness",), numerics=NUM, draws=16, jacobian_draws=4)
    one = aj.identify(truth, F, sims[0].x, sims[0].fh, **kw)
    both = aj.identify([aj.Recording(truth, F, s.x, s.fh, group="a") for s in sims], **kw)
    assert one.converged and both.converged, (one.message, both.message)
    # the mean of two recordings spreads as one over two; the binding's own MC error adds 1/R
    ratio = np.asarray(both.se["arm.stiffness"]) / np.asarray(one.se["arm.stiffness"])
    # each SE rests on its own Jacobian at its own estimate (4 draws): entry by entry within 20%
    want = np.sqrt((0.5 + 1 / 16) / (1 + 1 / 16))
    np.testing.assert_allclose(ratio, want, rtol=0.2)
    np.testing.assert_allclose(ratio.mean(), want, rtol=0.08)
    assert len(both.recordings) == 2


@pytest.mark.slow  # about 200 s: three identifications beside the sensitivity
def test_the_sensitivity_to_a_force_gain_or_delay_error_is_identifys_own_move():
    """The first-order bias robot_sensitivity predicts for a force channel 1% too strong on the
    x axis, times 5, is the move of identify's estimate on one recording when its model's gain
    is 5% off within 0.6 SE on every entry (measured 0.55 on K[0,0]: identify centres its
    statistic per recording, the prediction at the truth; docs/identification.md 4c), and the
    x-axis mass, moved by about one SE, moves the way it says. Its per-ms column is
    the move when the model's force delay is 1 ms and the recording's none: within 0.75 SE on
    every entry (measured 0.61 on M[1,1]) and 15% on the damping's diagonal (measured 5% and
    2%: 1.5 and 1.8 SE each)."""
    trial = aj.make_trial(aj.PD(), arm=paper.arm(2), friction=aj.NO_FRICTION, **NOISE)
    kw = dict(numerics=NUM, draws=16, jacobian_draws=4)
    s = aj.experiment.robot_sensitivity(trial, F, robot=("sensors.force_gain", "sensors.force_delay"), **kw)
    assert s.robot_labels == ["sensors.force_gain[0]", "sensors.force_gain[1]", "sensors.force_delay (per ms)"]
    np.testing.assert_allclose(s.in_se, s.bias_per_percent / s.se[:, None])
    sim = _sim(trial, key=jax.random.key(11))
    right = aj.identify(trial, F, sim.x, sim.fh, free=ARM, **kw)
    off = dataclasses.replace(trial, sensors=dataclasses.replace(trial.sensors, force_gain=[1.05, 1.0]))
    wrong = aj.identify(off, F, sim.x, sim.fh, free=ARM, **kw)
    assert right.converged and wrong.converged, (right.message, wrong.message)
    move = np.concatenate([np.ravel(wrong.values[n] - right.values[n]) for n in ARM]) / 5.0
    np.testing.assert_array_less(5.0 * np.abs(s.bias_per_percent[:, 0] - move), 0.6 * s.se)
    i = s.arm_labels.index("arm.mass[0,0]")
    assert s.bias_per_percent[i, 0] < 0 and move[i] < 0  # the x row reads a weaker push
    late = dataclasses.replace(trial, sensors=dataclasses.replace(trial.sensors, force_delay=0.001))
    delayed = aj.identify(late, F, sim.x, sim.fh, free=ARM, **kw)
    assert delayed.converged, delayed.message
    move = np.concatenate([np.ravel(delayed.values[n] - right.values[n]) for n in ARM])
    np.testing.assert_array_less(np.abs(s.bias_per_percent[:, 2] - move), 0.75 * s.se)
    for label in ("arm.damping[0,0]", "arm.damping[1,1]"):
        i = s.arm_labels.index(label)
        np.testing.assert_allclose(s.bias_per_percent[i, 2], move[i], rtol=0.15)


def test_robot_sensitivity_refuses_what_it_cannot_weigh_in_one_line():
    """A calibration error of 0% and a delay on a force from the motor torques are refused before
    any simulation; the delay is probed only where the robot has a force transducer."""
    from armimp_jax._design.sensitivity import robot_names

    trial = aj.make_trial(aj.PD(), arm=paper.arm(2), friction=aj.NO_FRICTION, **NOISE)
    assert robot_names(trial)[-1] == "sensors.force_delay"
    with pytest.raises(ValueError, match=r"^robot_sensitivity: plausible must be > 0%, got 0$"):
        aj.experiment.robot_sensitivity(trial, F, plausible=0)
    with pytest.raises(ValueError, match=r"plausible_delay_ms must be > 0 ms, got -1"):
        aj.experiment.robot_sensitivity(trial, F, plausible_delay_ms=-1)
    motor = aj.Sensors(force_noise=0.05, force_model=aj.presets.MIT_MANUS)
    no_transducer = dataclasses.replace(trial, sensors=motor)
    assert "sensors.force_delay" not in robot_names(no_transducer)
    with pytest.raises(ValueError, match="a force from the motor torques has no force-channel delay"):
        aj.experiment.robot_sensitivity(no_transducer, F, robot="sensors.force_delay")
    # the force channel's calibration is simulated under the instant acquisition only
    mean = aj.make_trial(aj.PD(), arm=paper.arm(2), friction=aj.NO_FRICTION, acquisition="interval_mean", **NOISE)
    assert not any(n.startswith("sensors.") for n in robot_names(mean))
    with pytest.raises(ValueError, match="gain and delay need acquisition 'instant', got 'interval_mean'"):
        aj.experiment.robot_sensitivity(mean, F, robot="sensors.force_gain")
    # a delay line too short for a 1 ms secant either way (7 periods of 0.1 ms)
    fast = aj.make_trial(aj.PD(), arm=paper.arm(2), friction=aj.NO_FRICTION, period=1e-4, **NOISE)
    with pytest.raises(ValueError, match=r"the force delay line holds 0.7 ms at a 0.1 ms period, too short"):
        aj.experiment.robot_sensitivity(fast, F, robot="sensors.force_delay")


def test_the_entrywise_cells_change_one_factor_each_from_the_base_case():
    """Issue 50's design: every cell is the base case (IMBIC, LuGre 0.5 N m, 0.5 N of the
    person's force below 1.5 Hz, force noise 0.1 N, 10 s, arm 2) with one factor changed, and
    its settings are plain JSON."""
    import json

    from armimp_bench import entrywise as ew

    base = ew.BASE.truth()
    assert isinstance(base.controller, aj.IMBIC) and float(base.friction.tau_c[0]) == 0.5
    assert float(np.ravel(base.voluntary.std)[0]) == 0.5 and float(base.sensors.force_noise[0]) == 0.1
    for name, cell in ew.CELLS_FACTORS.items():
        changed = {k for k, v in dataclasses.asdict(cell).items() if v != getattr(ew.BASE, k)}
        allowed = {"pd": 3, "friction-1-arm-4": 2}.get(name, 1)  # PD's three; the second arm at the worst cell
        assert len(changed) <= allowed, (name, changed)
    assert ew.CELLS_FACTORS["friction-0"].free() == ARM  # no Coulomb torque to estimate
    assert ew.CELLS_FACTORS["base"].free() == (*ARM, "friction.tau_c")
    assert json.loads(json.dumps(ew.settings()))["pd"] == dict(
        controller="pd", tau_c=0.3, voluntary=0.5, seconds=10.0, location=2, peak=10.0
    )
