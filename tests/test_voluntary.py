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
        s = aj.simulate(t, f_delta, key=key, numerics=aj.SWEEP_NUMERICS)
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
