"""The README's two commands are the ones CI and users run."""

import pathlib
import re

import numpy as np
import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]


def _commands():
    readme = (ROOT / "README.md").read_text()
    return re.findall(r"```bash\n(.*?)```", readme, flags=re.S)


def test_ci_runs_exactly_the_readme_test_command():
    ci = (ROOT / ".ci" / "run").read_text().strip().splitlines()[-1]
    assert any(ci in block for block in _commands()), ci


def test_readme_main_command_runs_the_reproduction():
    assert any("python sweeps/reproduce_paper.py" in block and "pip install" in block for block in _commands())


def test_readme_library_example_runs(capsys):
    """The README's quick start, verbatim: a custom arm and friction, noise, a fit, a batch, a
    gradient; it prints phi_T and, at the defaults, every element of M, B, K with its 95% interval
    (each holding the truth here) and the fit's warnings."""
    import jax

    readme = (ROOT / "README.md").read_text()
    code = re.findall(r"```python\n(.*?)```", readme, flags=re.S)[0]
    scope: dict = {}
    exec(compile(code, "README.md", "exec"), scope)
    # phi_T as the paper defines it (eqs. 1-2), computed here: the mean over the bins of the largest
    # singular value of Z_h(j 2 pi f) - Z_hat(f), with Z_h = K + j w B - w^2 M of the README's arm
    est, arm = scope["est"], scope["arm"]
    s = 2j * np.pi * np.asarray(est.f)[:, None, None]
    z_h = np.asarray(arm.mass) * s**2 + np.asarray(arm.damping) * s + np.asarray(arm.stiffness)
    phi_t = np.linalg.norm(z_h - np.asarray(est.Z), 2, axis=(1, 2)).mean()
    assert float(scope["phi_T"]) == pytest.approx(phi_t, rel=1e-12)
    assert phi_t < 0.1 * np.linalg.norm(z_h, 2, axis=(1, 2)).mean()  # within claim (a)'s 10% of mean |Z_h|
    assert scope["sims"].x.shape == (3, 12_000, 2)
    fit = scope["fit"]
    np.testing.assert_allclose(fit.mass, arm.mass, atol=0.15)  # [kg]
    assert fit.vaf_overall > 95.0
    out = capsys.readouterr().out
    assert f"phi_T = {float(scope['phi_T']):.0f} N/m" in out
    # fit.summary() with no option beyond the defaults: twelve 95% intervals, then the warnings
    printed = re.findall(r"^([MBK])([xy])([xy]) \[[^]]+\]\s+(\S+)\s+\[(\S+), (\S+)\]$", out, flags=re.M)
    assert len(printed) == 12
    for sym, i, j, value, low, high in printed:
        name = dict(M="mass", B="damping", K="stiffness")[sym]
        ij = "xy".index(i), "xy".index(j)
        lo, hi = fit.interval(name)
        assert float(value) == pytest.approx(float(np.asarray(getattr(fit, name))[ij]), rel=1e-3)
        assert (float(low), float(high)) == pytest.approx((lo[ij], hi[ij]), rel=1e-3, abs=1e-3)
        assert float(low) <= float(np.asarray(getattr(arm, name))[ij]) <= float(high), (sym, i, j)  # they hold here
    assert [line[len("WARNING: ") :] for line in out.splitlines() if line.startswith("WARNING: ")] == fit.warnings
    assert not any(w.startswith("implausible") for w in fit.warnings)  # the plausibility guard is silent here
    jax.config.update("jax_enable_x64", True)
