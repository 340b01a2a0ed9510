"""Welch spectra, H1, coherences and accuracy against scipy, theory and the simulator."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.signal

import armimp_jax as aj
from armimp_jax import paper
from armimp_jax._estimation.metrics import largest_singular_value
from armimp_jax._estimation.welch import cross_spectral_matrix


@pytest.mark.parametrize("n, nperseg, noverlap", [(50_000, 8192, 6144), (3000, 256, 192), (1000, 300, 100)])
def test_cross_spectra_equal_scipy_csd(n, nperseg, noverlap):
    x = np.random.default_rng(1).standard_normal((n, 3)).cumsum(axis=0)  # red, with a mean
    f, g = cross_spectral_matrix(jnp.asarray(x), fs=1000.0, nperseg=nperseg, noverlap=noverlap)
    for a in range(3):
        for b in range(3):
            fs_, ref = scipy.signal.csd(x[:, a], x[:, b], fs=1000.0, nperseg=nperseg, noverlap=noverlap)
            np.testing.assert_allclose(f, fs_, rtol=1e-15)
            np.testing.assert_allclose(g[:, a, b], ref, rtol=1e-12, atol=1e-12 * np.abs(ref).max())


def test_conjugation_convention_with_a_known_delay():
    """b(t) = a(t - d): G_ab = E[conj(A) B] has phase -2 pi f d (scipy's convention)."""
    a = np.random.default_rng(2).standard_normal(20_000)
    d = 3
    b = np.concatenate([np.zeros(d), a[:-d]])
    f, g = cross_spectral_matrix(jnp.asarray(np.stack([a, b], 1)), fs=1000.0, nperseg=512, noverlap=256)
    band = (f > 5) & (f < 200)
    phasor = np.asarray(g[band, 0, 1]) / np.abs(np.asarray(g[band, 0, 1]))
    np.testing.assert_allclose(phasor, np.exp(-2j * np.pi * f[band] * d / 1000.0), atol=0.02)


# A known 2-input 2-output discrete system: y_k = sum_i filter_ki(u_i).
FILTERS = {
    (0, 0): ([0.2, 0.1], [1.0, -0.6]),
    (0, 1): ([0.05, -0.02], [1.0, -0.3]),
    (1, 0): ([-0.1], [1.0, -0.8, 0.2]),
    (1, 1): ([0.3, 0.2, 0.1], [1.0]),
}


def _synthetic(n=60_000, noise=0.0, seed=0):
    rng = np.random.default_rng(seed)
    u = scipy.signal.lfilter([1.0], [1.0, -0.5], rng.standard_normal((n, 2)), axis=0)
    u[:, 1] += 0.3 * u[:, 0]  # correlated inputs, as a real experiment may have
    y = np.zeros((n, 2))
    for (k, i), (b, a) in FILTERS.items():
        y[:, k] += scipy.signal.lfilter(b, a, u[:, i])
    n_out = noise * rng.standard_normal((n, 2))
    return u, y, n_out


def _true_h(f, fs=1000.0):
    h = np.zeros((len(f), 2, 2), complex)
    for (k, i), (b, a) in FILTERS.items():
        h[:, k, i] = scipy.signal.freqz(b, a, worN=f, fs=fs)[1]
    return h


def test_h1_recovers_a_known_mimo_system_with_unit_coherence():
    u, y, _ = _synthetic()
    est = aj.estimate(u, y, 2.0 * y, nperseg=1024, noverlap=512, fmax=400.0)
    h = _true_h(np.asarray(est.f))
    np.testing.assert_allclose(est.R, h, rtol=0, atol=2e-3 * np.abs(h).max())
    np.testing.assert_allclose(est.T, 2 * h, rtol=0, atol=4e-3 * np.abs(h).max())
    np.testing.assert_allclose(est.Z, np.broadcast_to(2 * np.eye(2), est.Z.shape), atol=1e-9)
    assert np.all(np.asarray(est.coh_multiple_x) > 0.999)


def test_output_noise_lowers_multiple_coherence_as_theory_says():
    """gamma2 = S_ss / (S_ss + S_nn) for independent output noise n."""
    u, y, n_out = _synthetic(noise=0.3)
    kw = dict(fs=1000.0, nperseg=1024, noverlap=512)
    est = aj.estimate(u, y + n_out, y, fmax=400.0, **kw)
    _, gs = cross_spectral_matrix(jnp.asarray(y), **kw)
    _, gn = cross_spectral_matrix(jnp.asarray(n_out), **kw)
    k = len(est.f)
    s_ss = np.real(np.stack([gs[1 : k + 1, 0, 0], gs[1 : k + 1, 1, 1]], -1))
    s_nn = np.real(np.stack([gn[1 : k + 1, 0, 0], gn[1 : k + 1, 1, 1]], -1))
    theory = s_ss / (s_ss + s_nn)
    assert np.all(np.asarray(est.coh_multiple_x) < 0.99) and np.all(np.asarray(est.coh_multiple_fh) > 0.999)
    err = np.asarray(est.coh_multiple_x) - theory
    # ~117 segments: single-bin scatter of a few hundredths, no bias on average
    assert np.sqrt(np.mean(err**2)) < 0.04 and np.abs(err).max() < 0.2
    assert abs(float(np.mean(err))) < 0.01


def test_multiple_partial_ordinary_identity():
    u, y, n_out = _synthetic(noise=0.5, n=20_000)
    kw = dict(fs=1000.0, nperseg=512, noverlap=256)
    est = aj.estimate(u, y + n_out, y, fmax=400.0, **kw)
    _, g = cross_spectral_matrix(jnp.asarray(np.concatenate([u, y + n_out], 1)), **kw)
    g = g[1 : len(est.f) + 1]
    for out in range(2):
        for j, o in ((0, 1), (1, 0)):
            ordinary_l = np.abs(g[:, o, 2 + out]) ** 2 / np.real(g[:, o, o] * g[:, 2 + out, 2 + out])
            lhs = 1 - est.coh_multiple_x[:, out]
            rhs = (1 - ordinary_l) * (1 - est.coh_partial_x[:, out, j])
            np.testing.assert_allclose(lhs, rhs, rtol=1e-10, atol=1e-12)


def test_largest_singular_value_and_accuracy():
    a = np.random.default_rng(3).standard_normal((50, 2, 2)) + 1j * np.random.default_rng(4).standard_normal((50, 2, 2))
    np.testing.assert_allclose(largest_singular_value(jnp.asarray(a)), np.linalg.norm(a, 2, axis=(1, 2)), rtol=1e-13)
    f = jnp.linspace(0.1, 15, 40)
    phi_t, phi_ij = aj.spectra.accuracy(paper.arm(2).impedance(f), f, paper.arm(2))
    assert float(phi_t) == 0.0 and np.all(np.asarray(phi_ij) == 0.0)
    z = paper.arm(1).impedance(f) + 10.0
    phi_t, phi_ij = aj.spectra.accuracy(z, f, paper.arm(1))
    np.testing.assert_allclose(phi_t, 20.0, rtol=1e-12)  # ||10 * ones(2,2)||_2 = 20
    np.testing.assert_allclose(phi_ij, 10.0, rtol=1e-12)


def test_true_impedance_matches_table_and_vmaps_over_arms():
    f = jnp.array([0.0, 1.0])
    arm = paper.arm(3)
    z = arm.impedance(f)
    np.testing.assert_allclose(z[0], arm.stiffness)
    s = 2j * np.pi
    np.testing.assert_allclose(z[1], arm.mass * s**2 + arm.damping * s + arm.stiffness, rtol=1e-15)
    arms = jax.tree.map(lambda *xs: jnp.stack(xs), *[paper.arm(loc) for loc in (1, 2, 3, 4)])
    zs = jax.vmap(lambda a: a.impedance(f))(arms)
    np.testing.assert_allclose(zs[2], z)


def _short_trial(friction_level, n=12_288, substeps=20):
    fd = aj.perturbation(jax.random.PRNGKey(5), n, paper.perturbation_peak(1))
    run = jax.jit(aj.simulate, static_argnames="numerics")
    r = run(paper.trial("pd", friction_level, 1), fd, numerics=aj.Numerics(solver=aj.solvers.RK4(), substeps=substeps))
    return fd, r


def test_end_to_end_pd_frictionless_is_accurate_and_friction_ruins_it():
    kw = dict(nperseg=2048, noverlap=1536)
    results = {}
    for level in (0, 2):
        fd, r = _short_trial(level)
        est = aj.estimate(fd, r.x, r.fh, **kw)
        phi_t, _ = aj.spectra.accuracy(est.Z, est.f, paper.arm(1))
        scale = float(jnp.mean(largest_singular_value(paper.arm(1).impedance(est.f))))
        results[level] = (float(phi_t) / scale, est)
    assert results[0][0] < 0.1, results[0][0]
    assert results[2][0] > 10 * results[0][0]
    # friction drives the coherence down at low frequency (the paper's Fig. 3)
    low = np.asarray(results[2][1].f) < 1.0
    assert np.asarray(results[2][1].coh_multiple_x)[low].min() < np.asarray(results[0][1].coh_multiple_x)[low].min()


@pytest.mark.slow  # test_trial checks phi_T gradients through the estimator fast
def test_gradient_of_phi_through_estimate_matches_finite_differences():
    fd, r = _short_trial(0, n=4096, substeps=10)
    kw = dict(nperseg=1024, noverlap=768)

    def phi(a):  # a feed-through of the perturbation into the force: a smooth scalar family
        est = aj.estimate(fd, r.x, r.fh + a * fd, **kw)
        return aj.spectra.accuracy(est.Z, est.f, paper.arm(1))[0]

    a0, eps = 0.05, 1e-5
    g = jax.grad(phi)(a0)
    fdiff = (phi(a0 + eps) - phi(a0 - eps)) / (2 * eps)
    assert np.isfinite(g)
    np.testing.assert_allclose(g, fdiff, rtol=1e-6)


def test_estimate_vmaps_over_trials():
    fds = jnp.stack([aj.perturbation(jax.random.PRNGKey(i), 3000, 2.25) for i in range(3)])
    xs, fhs = fds * 1e-3, fds * 0.5
    batched = jax.vmap(lambda a, b, c: aj.estimate(a, b, c, nperseg=1024, noverlap=512))(fds, xs, fhs)
    single = aj.estimate(fds[1], xs[1], fhs[1], nperseg=1024, noverlap=512)
    np.testing.assert_allclose(batched.Z[1], single.Z, rtol=1e-12)


def _scipy_h1(u, y, fmax, **kw):
    """H1 ``[output, input]`` from ``scipy.signal.csd`` on the bins ``0 < f <= fmax``."""
    f, _ = scipy.signal.csd(u[:, 0], u[:, 0], **kw)
    band = (f > 0) & (f <= fmax)
    guu = np.array([[scipy.signal.csd(u[:, i], u[:, j], **kw)[1][band] for j in range(2)] for i in range(2)])
    guy = np.array([[scipy.signal.csd(u[:, i], y[:, k], **kw)[1][band] for k in range(2)] for i in range(2)])
    h_t = np.linalg.solve(np.moveaxis(guu, -1, 0), np.moveaxis(guy, -1, 0))  # H^T = G_uu^-1 G_uy
    return f[band], np.swapaxes(h_t, -1, -2)


@pytest.mark.parametrize(
    "window, nfft",
    [(("tukey", 0.25), 2048), ("hamming", 1500), ("blackmanharris", 1001), ("boxcar", None)],
)
def test_window_and_nfft_give_scipy_csd_h1(window, nfft):
    """A non-default window and zero padding: R, T, Z and the inputs' coherence equal H1 and
    the coherence built from ``scipy.signal.csd`` with the same settings."""
    u, y, n_out = _synthetic(n=12_000, noise=0.2)
    fh = 3.0 * y + 0.1 * n_out[:, ::-1]
    kw = dict(fs=1000.0, nperseg=1000, noverlap=600, window=window, nfft=nfft)
    est = aj.estimate(u, y + n_out, fh, fmax=100.0, **kw)
    f, r = _scipy_h1(u, y + n_out, 100.0, **kw)
    _, t = _scipy_h1(u, fh, 100.0, **kw)
    np.testing.assert_allclose(est.f, f, rtol=1e-14)
    assert len(f) == int(100.0 * (nfft or 1000) / 1000.0)  # bins fs / nfft apart
    np.testing.assert_allclose(est.R, r, rtol=1e-10, atol=1e-12 * np.abs(r).max())
    np.testing.assert_allclose(est.T, t, rtol=1e-10, atol=1e-12 * np.abs(t).max())
    np.testing.assert_allclose(est.Z, t @ np.linalg.inv(r), rtol=1e-9)
    _, coh = scipy.signal.coherence(u[:, 0], u[:, 1], **kw)
    np.testing.assert_allclose(est.coh_inputs, coh[1 : len(f) + 1], rtol=1e-9, atol=1e-13)


def test_window_array_and_welch_settings_pass_through_assess():
    """And ``assess`` scores the estimate as the paper defines it (eqs. 1-2), computed here: phi_T the
    mean over the bins of the largest singular value of Z_h(j 2 pi f) - Z_hat(f), Z_h = K + j w B -
    w^2 M of the trial's arm; phi_ij each entry's mean modulus; the largest input coherence; the
    simulation's divergence passed on."""
    u, y, _ = _synthetic(n=6000, noise=0.1)
    kw = dict(nperseg=512, noverlap=256, fmax=50.0, nfft=640)
    named = aj.estimate(u, y, 2.0 * y + u, window=("kaiser", 6.0), **kw)
    given = aj.estimate(u, y, 2.0 * y + u, window=scipy.signal.get_window(("kaiser", 6.0), 512), **kw)
    np.testing.assert_array_equal(named.Z, given.Z)
    _, g = cross_spectral_matrix(jnp.asarray(u), nperseg=512, noverlap=256, window="hann", nfft=640)
    np.testing.assert_allclose(g[:, 0, 1], scipy.signal.csd(u[:, 0], u[:, 1], fs=1000.0, nperseg=512, nfft=640)[1])
    zeros = jnp.zeros_like(jnp.asarray(y))
    sim = aj.results.SimResult(y, zeros, 2.0 * y + u, zeros, zeros, zeros, jnp.bool_(True), jnp.int32(4321))
    welch = aj.Welch(512, 256, 50.0, window=("kaiser", 6.0), nfft=640)
    trial = paper.trial("pd", 0, 1)
    out = aj.batch.assess(trial, u, sim, welch)
    np.testing.assert_array_equal(out.estimate.Z, named.Z)
    s = 2j * np.pi * np.asarray(named.f)[:, None, None]
    z_h = np.asarray(trial.arm.mass) * s**2 + np.asarray(trial.arm.damping) * s + np.asarray(trial.arm.stiffness)
    err = z_h - np.asarray(named.Z)
    np.testing.assert_allclose(out.phi_T, np.linalg.norm(err, 2, axis=(1, 2)).mean(), rtol=1e-12)
    np.testing.assert_allclose(out.phi_ij, np.abs(err).mean(axis=0), rtol=1e-12)
    assert float(out.input_coherence) == float(np.max(np.asarray(out.estimate.coh_inputs)))
    assert bool(out.diverged) and int(out.diverged_at) == 4321
    with pytest.raises(ValueError, match="which give 1 Welch segment"):
        aj.Welch(512, 256).check(767)


@pytest.mark.parametrize(
    "n, kwargs, message",
    [
        (1000, dict(nperseg=2048, noverlap=1024), "shorter than one Welch segment"),
        (1000, dict(nperseg=1000, noverlap=0), r"which give 1 Welch segment .* at least 2 .* >= 2000 samples"),
        (1535, dict(nperseg=1024, noverlap=512), r"which give 1 Welch segment \(nperseg=1024, noverlap=512\)"),
        (5000, dict(nperseg=1024, noverlap=512, nfft=1000), "nfft must be >= 1024"),
        (5000, dict(nperseg=1024, noverlap=512, window="nope"), "window 'nope' is not one scipy"),
        (5000, dict(nperseg=1024, noverlap=512, window=np.ones(1000)), r"window array must have shape \(nperseg,\)"),
        (5000, dict(nperseg=1024, noverlap=512, fs=0.0), "fs must be a finite sample rate > 0 Hz"),
        (5000, dict(nperseg=1024, noverlap=1024), "noverlap must be smaller than nperseg=1024"),
        (5000, dict(nperseg=1024, noverlap=512, fmax=600.0), "fmax must lie between"),
        (5000, dict(nperseg=1024, noverlap=512, fmax=0.1), "fmax must lie between"),
    ],
)
def test_bad_welch_settings_are_rejected(n, kwargs, message):
    a = jnp.zeros((n, 2))
    with pytest.raises(ValueError, match=message):
        aj.estimate(a, a, a, **kwargs)


def test_mismatched_lengths_are_rejected():
    with pytest.raises(ValueError, match=r"same shape \(N, 2\)"):
        aj.estimate(jnp.zeros((5000, 2)), jnp.zeros((4999, 2)), jnp.zeros((5000, 2)), nperseg=1024, noverlap=512)


def test_accuracy_checks_its_arguments():
    with pytest.raises(ValueError, match="unknown arm location 0"):
        paper.arm(0)
    f = jnp.linspace(1, 10, 5)
    with pytest.raises(ValueError, match="arm must be an Arm"):
        aj.spectra.accuracy(jnp.zeros((5, 2, 2)), f, 1)
    with pytest.raises(ValueError, match=r"Z must have shape \(F, 2, 2\)"):
        aj.spectra.accuracy(jnp.zeros((4, 2, 2)), f, paper.arm(1))


@pytest.mark.parametrize("name, row, col", [("f_delta", 0, 0), ("x", 41, 1), ("fh", 3000, 0)])
def test_non_finite_record_names_the_array_and_the_first_bad_sample(name, row, col):
    u, y, _ = _synthetic(n=5000)
    arrays = {"f_delta": u, "x": y, "fh": 2.0 * y}
    arrays[name] = arrays[name].copy()
    arrays[name][row, col] = np.nan
    arrays[name][3500, 1] = np.inf  # a later bad value: the first one is named
    with pytest.raises(
        ValueError, match=rf"estimate: {name} holds a non-finite value, nan, at sample {row}, column {col}"
    ):
        aj.estimate(arrays["f_delta"], arrays["x"], arrays["fh"], nperseg=1024, noverlap=512)
    # traced values are not inspected (the batch pipeline reports diverged trials itself)
    est = jax.jit(lambda a, b, c: aj.estimate(a, b, c, nperseg=1024, noverlap=512))(
        arrays["f_delta"], arrays["x"], arrays["fh"]
    )
    assert not np.all(np.isfinite(est.Z))


def test_the_error_model_leaves_the_estimate_unchanged():
    u, y, n_out = _synthetic(n=20_000, noise=0.1)
    plain = aj.estimate(u, y + n_out, 2.0 * y, nperseg=2048, noverlap=1536, errors=False)
    with_errors = aj.estimate(u, y + n_out, 2.0 * y, nperseg=2048, noverlap=1536)  # the default
    assert plain.error is None and with_errors.error is not None
    for field in (f for f in plain._fields if f != "error"):
        np.testing.assert_array_equal(getattr(with_errors, field), getattr(plain, field), err_msg=field)


def test_error_model_predicts_the_variance_and_bin_correlation_of_z():
    """Z = K exactly (no leakage from a varying Z), white force noise, 29 Hann segments with
    75% overlap: over 300 records the per-bin variance of Z is the error model's (measured
    0.95-0.97 of it; without the overlap and fitted-averages corrections the model would be
    off by about 1.6), and neighbouring bins' errors correlate as ``bin_corr[1]`` (0.49 for
    Hann at 75%)."""
    n, k = 16_384, np.array([[105.72, -104.11], [-127.35, 234.78]])

    def record(key):
        k1, k2 = jax.random.split(key)
        w = jnp.fft.rfftfreq(n, 1e-3)
        u = jnp.fft.irfft(
            jnp.fft.rfft(jax.random.normal(k1, (n, 2)), axis=0) / (1 + 1j * w / 20.0)[:, None], n=n, axis=0
        )
        x = 1e-2 * u @ jnp.array([[1.0, 0.3], [0.2, 1.0]]).T
        return aj.estimate(
            u, x, x @ k.T + 0.5 * jax.random.normal(k2, (n, 2)), nperseg=2048, noverlap=1536, errors=True
        )

    ests = jax.jit(jax.vmap(record))(jax.random.split(jax.random.PRNGKey(0), 300))
    z = np.asarray(ests.Z)
    emp = z.var(axis=0)  # (F, 2, 2)
    pred = np.mean(np.einsum("nfii,nfjj->nfij", ests.error.force, ests.error.position).real, axis=0)
    np.testing.assert_allclose(np.median(emp / pred, axis=0), 1.0, atol=0.1)
    d = z - z.mean(axis=0)
    corr = np.mean(d[:, :-1] * np.conj(d[:, 1:]), axis=0) / np.sqrt(emp[:-1] * emp[1:])
    np.testing.assert_allclose(np.median(corr.real), ests.error.bin_corr[0, 1], atol=0.05)
    np.testing.assert_allclose(ests.error.bin_corr[0, 1], 0.489, atol=0.005)


def test_welch_segments_follow_the_record():
    """Table 4's 8192/6144 from 24576 samples on (the paper's records unchanged); a 12 s record
    at 1 kHz gets 2048-sample segments (20 of them, not Table 4's 2); a given nperseg alone
    gets 75% overlap; the default estimate uses exactly these settings."""
    assert aj.spectra.welch_segments(50_000) == (8192, 6144) == aj.spectra.welch_segments(24_576)
    assert aj.spectra.welch_segments(12_000) == (2048, 1536)
    assert aj.spectra.welch_segments(24_575) == (4096, 3072)
    with pytest.raises(ValueError, match="n_samples"):
        aj.spectra.welch_segments(8)
    u, y, n_out = _synthetic(n=12_000, noise=0.1)
    auto = aj.estimate(u, y + n_out, 2.0 * y, errors=False)
    given = aj.estimate(u, y + n_out, 2.0 * y, nperseg=2048, errors=False)
    explicit = aj.estimate(u, y + n_out, 2.0 * y, nperseg=2048, noverlap=1536, errors=False)
    for field in ("f", "Z", "coh_inputs"):
        np.testing.assert_array_equal(getattr(auto, field), getattr(explicit, field))
        np.testing.assert_array_equal(getattr(given, field), getattr(explicit, field))


def test_a_sweeps_phase_error_skips_entries_whose_truth_is_zero():
    """An arm without cross-coupling has off-diagonal impedances of zero, whose phase is undefined:
    the sweep's phase error is the mean over the diagonal, here 10 degrees on each (a Z_hat that
    is the truth turned by 10 degrees), not NaN."""
    from armimp_jax.study.sweep.metrics import score

    diagonal = dict(mass=np.diag([1.0, 2.0]), damping=np.diag([5.0, 6.0]), stiffness=np.diag([100.0, 200.0]))
    arm = aj.Arm(**diagonal, endpoint=[0.0, 0.4])
    f = np.linspace(0.5, 10.0, 20)
    z = np.asarray(arm.impedance(f)) * np.exp(1j * np.radians(10.0))
    ones = np.ones((len(f), 2))
    names = ("coh_multiple_x", "coh_partial_x", "coh_multiple_fh", "coh_partial_fh", "coh_inputs")
    coherences = dict.fromkeys(names, ones)
    m = score(f, z, coherences, arm)
    assert m["phase_error_deg"] == pytest.approx(10.0, rel=1e-12)
