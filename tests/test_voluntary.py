"""The person's own force F_v (armimp_jax._model.voluntary; docs/model.md section 17)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import armimp_jax as aj
from armimp_jax import paper
from armimp_jax._model.voluntary import VoluntaryForce, voluntary_force

VOL = VoluntaryForce(std=0.3, cutoff=2.0)


def test_stationary_rms_from_the_first_sample_and_band_limited():
    # over many keys, the first samples already have the stationary RMS (the filter starts there)
    keys = jax.random.split(jax.random.PRNGKey(0), 2000)
    first = jax.vmap(lambda k: voluntary_force(VOL, k, 3))(keys)  # (2000, 3, 2)
    np.testing.assert_allclose(np.sqrt(np.mean(np.asarray(first) ** 2, axis=0)), 0.3, rtol=0.08)
    # one long record: the same RMS, and the power sits below the cut-off
    fv = np.asarray(voluntary_force(VOL, jax.random.PRNGKey(1), 400_000))
    np.testing.assert_allclose(np.sqrt(np.mean(fv**2, axis=0)), 0.3, rtol=0.1)
    spectrum = np.abs(np.fft.rfft(fv[:, 0])) ** 2
    f = np.fft.rfftfreq(fv.shape[0], 1e-3)
    assert spectrum[f < 2.0].sum() > 50 * spectrum[f > 20.0].sum()


def test_it_moves_the_arm_and_never_changes_the_sensor_noise_draws():
    f_delta = jnp.zeros((2000, 2))  # no perturbation: only the person's force moves the hand
    key = jax.random.PRNGKey(3)

    def fh(noise, vol):
        sensors = aj.Sensors(force_noise=0.05 if noise else 0.0, force_on=True)
        t = aj.make_trial(aj.PD(), arm=paper.arm(2), friction=aj.NO_FRICTION, sensors=sensors, voluntary=vol)
        s = aj.simulate(t, f_delta, key=key, numerics=aj.solvers.SWEEP_NUMERICS)
        return np.asarray(s.fh), np.asarray(s.x) - np.asarray(t.x0)

    (with_vol, x_vol), (quiet_vol, _) = fh(True, VOL), fh(False, VOL)
    (with_none, x_none), (quiet_none, _) = fh(True, None), fh(False, None)
    assert np.max(np.abs(x_vol)) > 1e-4 and np.max(np.abs(x_none)) == 0.0
    # PD does not feed the force back: the noise is what the recorded force adds, the same draws
    np.testing.assert_allclose(with_vol - quiet_vol, with_none - quiet_none, rtol=0, atol=1e-12)


def test_bad_settings_are_one_line_errors():
    with pytest.raises(ValueError, match="voluntary cutoff must be below the Nyquist rate 500 Hz, got 600 Hz"):
        aj.make_trial(aj.PD(), arm=paper.arm(1), friction=aj.NO_FRICTION, voluntary=VoluntaryForce(0.3, 600.0))
    t = aj.make_trial(aj.PD(), arm=paper.arm(1), friction=aj.NO_FRICTION, voluntary=VOL)
    with pytest.raises(ValueError, match="voluntary force is random; pass key="):
        aj.simulate(t, jnp.zeros((10, 2)))


def test_axes_independent_and_per_axis_levels():
    fv = np.asarray(voluntary_force(aj.VoluntaryForce([0.3, 0.6], 2.0), jax.random.PRNGKey(11), 400_000))
    np.testing.assert_allclose(np.sqrt(np.mean(fv**2, axis=0)), [0.3, 0.6], rtol=0.1)
    assert abs(np.corrcoef(fv[:, 0], fv[:, 1])[0, 1]) < 0.05


NUM = aj.solvers.SWEEP_NUMERICS


def _trial(voluntary, sensors=None, friction=None):
    return aj.make_trial(
        aj.PD(),
        arm=paper.arm(2),
        friction=aj.NO_FRICTION if friction is None else friction,
        sensors=sensors,
        voluntary=voluntary,
    )


def test_the_person_pushes_the_arm_and_the_transducer_reads_minus_that():
    """Spec 11c: M_h xdd + B_h xd + K_h (x - x0) = F_h + F_v on the arm, while the robot (no
    friction, PD) feels only -F_h: M_x xdd = F_u - F_h. A slow F_v and no perturbation."""
    from armimp_jax._model.robot import cartesian_inertia

    vol = aj.VoluntaryForce(2.0, 0.1)
    key = jax.random.key(3)
    n = 20_000
    trial = _trial(vol)
    sim = aj.simulate(trial, jnp.zeros((n, 2)), key=key, numerics=NUM)
    fv = np.asarray(voluntary_force(vol, key, n))
    dx, xd, fh = np.asarray(sim.x) - np.asarray(trial.x0), np.asarray(sim.xd), np.asarray(sim.fh)
    acc = np.gradient(xd, 1e-3, axis=0)
    arm = paper.arm(2)
    assert np.abs(fv).max() > 3.0
    # F_h,k is read just before the update, while F_v,k-1 still acts (measured: within 6.2e-4 N)
    passive = acc @ np.asarray(arm.mass).T + xd @ np.asarray(arm.damping).T + dx @ np.asarray(arm.stiffness).T
    np.testing.assert_allclose((fh[1:] + fv[:-1])[1000:-1], passive[1:][1000:-1], atol=7e-4)
    # the robot's side (measured within 4.1e-3 N: its inertia varies with the posture)
    robot = -(250.0 * dx + 4.0 * xd) - acc @ np.asarray(cartesian_inertia(trial.q0)).T
    np.testing.assert_allclose(fh[1000:-1], robot[1000:-1], atol=5e-3)
    # and F_v moved it: the arm's passive force is not the transducer's
    assert np.abs(fh - passive).max() > 1.0


def test_zero_force_keeps_every_sensor_noise_draw():
    sensors = aj.Sensors(force_noise=0.05, velocity_noise=1e-3)
    f = aj.perturbation(jax.random.key(4), 3000, 5.0)
    key = jax.random.key(5)
    off = aj.simulate(_trial(None, sensors, aj.LuGre(0.2, 0.3)), f, key=key, numerics=NUM)
    zero = aj.simulate(_trial(aj.VoluntaryForce(0.0, 2.0), sensors, aj.LuGre(0.2, 0.3)), f, key=key, numerics=NUM)
    on = aj.simulate(_trial(aj.VoluntaryForce(0.3, 2.0), sensors, aj.LuGre(0.2, 0.3)), f, key=key, numerics=NUM)
    np.testing.assert_array_equal(zero.x, off.x)
    np.testing.assert_array_equal(zero.fh, off.fh)
    assert np.abs(np.asarray(on.fh) - np.asarray(off.fh)).max() > 0.1


def test_chunks_chain_bitwise():
    trial = _trial(aj.VoluntaryForce(0.3, 2.0), aj.Sensors(force_noise=0.05), aj.LuGre(0.5, 0.75))
    f = aj.perturbation(jax.random.key(6), 2000, 5.0)
    key = jax.random.key(7)
    whole = aj.simulate(trial, f, key=key, numerics=NUM)
    carry = aj.solvers.simulate_init(trial)
    carry, a = aj.solvers.simulate_chunk(trial, carry, f[:700], key=key, numerics=NUM)
    carry, b = aj.solvers.simulate_chunk(trial, carry, f[700:], key=key, numerics=NUM)
    np.testing.assert_array_equal(np.concatenate([a.x, b.x]), whole.x)
    np.testing.assert_array_equal(np.concatenate([a.fh, b.fh]), whole.fh)


def test_more_bad_values_are_refused():
    with pytest.raises(ValueError, match="std"):
        aj.VoluntaryForce(-0.1, 2.0)
    with pytest.raises(ValueError, match="cutoff"):
        aj.VoluntaryForce(0.3, 0.0)
    with pytest.raises(ValueError, match="voluntary must be a VoluntaryForce"):
        _trial(0.3)
    with pytest.raises(ValueError, match="voluntary force of one cutoff"):
        aj.batch.stack_trials([_trial(None), _trial(aj.VoluntaryForce(0.3, 2.0))])
