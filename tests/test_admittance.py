"""Admittance control (issue 46): the whole sampled loop against its closed form written here
(virtual model, servo, the robot's inertia, the holds), its limit as the servo stiffens, the
linearised loop against the simulation with an arm, and the one-line refusals (a loop the arm
makes unstable among them, against the linearisation and the simulation)."""

import dataclasses
import re

import jax
import numpy as np
import pytest
import scipy.linalg

import armimp_jax as aj
from armimp_jax import paper
from armimp_jax._identification import linear
from armimp_jax._model.controllers.admittance import coupled_radius
from armimp_jax._model.plant import rest_plant
from armimp_jax._model.robot import cartesian_inertia

L = 1e-3
VIRTUAL = dict(m_v=2.0 * np.eye(2), b_v=10.0 * np.eye(2), k_v=50.0 * np.eye(2))
SERVO = dict(kp=4000.0 * np.eye(2), kv=60.0 * np.eye(2))
LINES_HZ = (0.5, 1.0, 2.0, 5.0, 10.0, 15.0, 20.0)
# Frictionless loops are not stiff: RK4 at 4 substeps integrates the robot to ~1e-10 here.
NUM = aj.Numerics(solver=aj.solvers.RK4(), substeps=4)


def closed_form(m_x, m_v, b_v, k_v, kp, kv, f_hz):
    """``(F, 2, 2)``: the hand's response ``x - x0`` to ``F_Delta`` of the sampled loop with no
    arm and no friction, from its state space written out here: the virtual model's exact
    zero-order hold, the servo's command from the new virtual state and the measured hand, and
    the robot as a Cartesian mass ``m_x`` under the held command (``z`` is one period)."""
    minv_v, minv_r = np.linalg.inv(m_v), np.linalg.inv(m_x)
    z2, eye = np.zeros((2, 2)), np.eye(2)
    a_v = np.block([[z2, eye], [-minv_v @ k_v, -minv_v @ b_v]])
    gen = np.zeros((6, 6))
    gen[:4, :4], gen[:4, 4:] = a_v, np.vstack([z2, minv_v])
    hold = scipy.linalg.expm(gen * L)
    phi, gamma = hold[:4, :4], hold[:4, 4:]
    # state (e, ed, w): w' = phi w + gamma u; F = kp (w'_pos - e) + kv (w'_vel - ed)
    f_state = np.hstack([-kp, -kv, kp @ phi[:2] + kv @ phi[2:]])
    f_input = kp @ gamma[:2] + kv @ gamma[2:]
    a = np.zeros((8, 8))
    b = np.zeros((8, 2))
    a[:2, :2], a[:2, 2:4] = eye, L * eye
    a[2:4, 2:4] = eye
    a[:4] += np.vstack([0.5 * L * L * minv_r, L * minv_r]) @ f_state
    b[:4] = np.vstack([0.5 * L * L * minv_r, L * minv_r]) @ f_input
    a[4:, 4:], b[4:] = phi, gamma
    c = np.hstack([eye, np.zeros((2, 6))])
    zs = np.exp(2j * np.pi * np.asarray(f_hz) * L)
    return np.stack([c @ np.linalg.solve(zk * np.eye(8) - a, b) for zk in zs])


def _measured_response(trial, seconds=8.0, window=4.0):
    """The simulated hand's response at ``LINES_HZ`` to sines on one axis at a time (DFT of the
    last ``window`` seconds, an integer number of every line's periods)."""
    n, w = int(seconds / L), int(window / L)
    t = np.arange(n) * L
    phases = np.random.default_rng(0).uniform(0, 2 * np.pi, len(LINES_HZ))
    sig = 0.3 * sum(np.sin(2 * np.pi * f * t + p) for f, p in zip(LINES_HZ, phases))
    inputs = np.zeros((2, n, 2))
    inputs[0, :, 0], inputs[1, :, 1] = sig, sig
    sims = jax.jit(jax.vmap(lambda fd: aj.simulate(trial, fd, numerics=NUM).x))(inputs)
    x = np.asarray(sims)[:, -w:] - np.asarray(trial.x0)
    bins = np.rint(np.asarray(LINES_HZ) * window).astype(int)
    fx = np.fft.rfft(x, axis=1)[:, bins]  # (input axis, line, output axis)
    fu = np.fft.rfft(inputs[:, -w:], axis=1)[:, bins]
    return np.stack([fx[j] / fu[j, :, j : j + 1] for j in range(2)], axis=-1)  # (line, out, in)


def test_the_loop_without_arm_or_friction_is_its_closed_form_to_1_percent_up_to_20_hz():
    arm = aj.presets.no_arm(paper.location_endpoint(1))
    trial = aj.make_trial(aj.Admittance(**VIRTUAL, **SERVO), arm=arm, friction=aj.NO_FRICTION)
    m_x = np.asarray(cartesian_inertia(trial.q0, trial.robot))
    want = closed_form(m_x, **VIRTUAL, **SERVO, f_hz=LINES_HZ)
    got = _measured_response(trial)
    err = np.linalg.norm(got - want, axis=(1, 2)) / np.linalg.norm(want, axis=(1, 2))
    assert np.all(err < 0.01), err
    # and the closed form is what the linearised loop says (its own F_Delta -> x map)
    loop = linear.loop_of(trial)
    a, b, c = (np.asarray(m) for m in (loop.a, loop.b[:, :2], loop.c[:2]))
    zs = np.exp(2j * np.pi * np.asarray(LINES_HZ) * L)
    lin = np.stack([c @ np.linalg.solve(zk * np.eye(len(a)) - a, b) for zk in zs])
    assert np.max(np.abs(lin - want)) / np.max(np.abs(want)) < 1e-3


def test_as_the_servo_stiffens_the_hand_follows_the_virtual_model():
    m_x = np.asarray(cartesian_inertia(paper.trial("pd", 0, 1).q0))
    f = np.array([0.5, 2.0, 5.0])
    s = 2j * np.pi * f[:, None, None]
    virtual = np.linalg.inv(VIRTUAL["m_v"] * s**2 + VIRTUAL["b_v"] * s + VIRTUAL["k_v"])
    gaps = []
    for scale in (1.0, 10.0, 100.0):  # kv by sqrt(scale): the servo's damping ratio kept
        h = closed_form(m_x, **VIRTUAL, kp=4000.0 * scale * np.eye(2), kv=60.0 * np.sqrt(scale) * np.eye(2), f_hz=f)
        gaps.append(np.max(np.abs(h - virtual)) / np.max(np.abs(virtual)))
    assert gaps[0] > gaps[1] > gaps[2] and gaps[2] < 0.01, gaps


def test_with_an_arm_the_linearised_loop_follows_the_simulation():
    trial = aj.make_trial(aj.Admittance(**VIRTUAL, **SERVO), arm=paper.arm(2), friction=aj.NO_FRICTION)
    f = aj.perturbation(jax.random.key(7), 2000, paper.perturbation_peak(1))
    y_lin = np.asarray(LINEARISED(trial, f)[1])
    sim = SIMULATE(trial, f, numerics=NUM)
    y = np.concatenate([np.asarray(sim.x) - np.asarray(trial.x0), np.asarray(sim.fh)], axis=1)
    err = np.sqrt(np.sum((y - y_lin) ** 2, axis=0) / np.sum(y**2, axis=0))
    assert np.all(err < 5e-3), err


# One program each for the tests that linearise or simulate an admittance trial with an arm.
LINEARISED = jax.jit(lambda t, f: (linear.linearise(t).a, linear.respond(linear.linearise(t), f)))
SIMULATE = jax.jit(aj.simulate, static_argnames="numerics")


def test_a_loop_the_arm_makes_unstable_is_refused_with_the_margin_and_diverges():
    """A virtual mass far below the arm's (0.001 kg): make_trial refuses it in one line with the
    loop's spectral radius, which is the simulation's own linearisation's (crlb's check) to
    round-off, and the virtual mass it names is where the loop turns stable. The same controller
    bound past the check diverges in simulation; the defaults (the README's lab) pass."""
    arm, fr = paper.arm(2), aj.LuGre(0.0, 0.0, sigma2=0.05)  # viscous alone: the programs of the test above
    good = aj.make_trial(aj.Admittance(**VIRTUAL, **SERVO), arm=arm, friction=fr)
    light = aj.Admittance(**(VIRTUAL | dict(m_v=0.001 * np.eye(2))), **SERVO)
    with pytest.raises(ValueError, match=r"unstable: spectral radius (\d\.\d+) per 0.001 s period") as err:
        aj.make_trial(light, arm=arm, friction=fr)
    message = str(err.value)
    assert "\n" not in message and "against the arm's [0.79, 1.56] kg" in message
    bound = light.bind(good.robot, good.q0, good.x0, period=good.period)
    bad = dataclasses.replace(good, controller=bound)  # past make_trial's check
    f = aj.perturbation(jax.random.key(7), 2000, paper.perturbation_peak(1))
    for trial, stable in ((good, True), (bad, False)):
        radius = float(np.max(np.abs(np.linalg.eigvals(np.asarray(LINEARISED(trial, f)[0])))))
        plant = rest_plant(trial.q0, trial.arm, trial.friction, trial.robot)
        c = trial.controller
        np.testing.assert_allclose(coupled_radius(c.phi, c.gamma, c.kp, c.kv, plant, np.ones(2), L), radius, rtol=1e-12)
        assert (radius < 1) == stable and bool(SIMULATE(trial, f, numerics=NUM).diverged) != stable
    shown = float(re.search(r"spectral radius (\d\.\d+)", message).group(1))
    assert shown == pytest.approx(radius, abs=1e-4)
    factor = float(re.search(r"or more \(([\d.]+) times it\)", message).group(1))
    aj.make_trial(aj.Admittance(**(VIRTUAL | dict(m_v=0.00101 * factor * np.eye(2))), **SERVO), arm=arm, friction=fr)
    with pytest.raises(ValueError, match="unstable: spectral radius"):
        aj.make_trial(
            aj.Admittance(**(VIRTUAL | dict(m_v=0.00095 * factor * np.eye(2))), **SERVO), arm=arm, friction=fr
        )


@pytest.mark.parametrize(
    "gains, message",
    [
        # a circulatory virtual stiffness (skew, its symmetric part zero) flutters
        (dict(k_v=[[0.0, 400.0], [-400.0, 0.0]], b_v=0.1 * np.eye(2)), "the virtual model (m_v, b_v, k_v) grows"),
        (dict(kp=1e7 * np.eye(2)), "the servo (kp, kv) is unstable on the robot's inertia"),
        (dict(b_v=-np.eye(2)), "Admittance: b_v must have a positive semi-definite symmetric part"),
        (dict(m_v=np.zeros((2, 2))), "Admittance: m_v must have a positive definite symmetric part"),
    ],
)
def test_an_unstable_or_invalid_admittance_is_refused_in_one_line(gains, message):
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)")) as err:
        aj.make_trial(aj.Admittance(**gains), arm=paper.arm(1), friction=aj.NO_FRICTION)
    assert "\n" not in str(err.value)
