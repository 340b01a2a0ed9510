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
    gradient; it prints phi_T and every element of M, B, K with its 95% interval beside the truth."""
    import jax

    readme = (ROOT / "README.md").read_text()
    code = re.findall(r"```python\n(.*?)```", readme, flags=re.S)[0]
    scope: dict = {}
    exec(compile(code, "README.md", "exec"), scope)
    assert 100.0 < float(scope["phi_T"]) < 1000.0
    assert scope["sims"].x.shape == (3, 12_000, 2)
    fit, arm = scope["fit"], scope["arm"]
    np.testing.assert_allclose(fit.mass, arm.mass, atol=0.15)  # [kg]
    assert fit.vaf_overall > 95.0
    out = capsys.readouterr().out
    assert f"phi_T = {float(scope['phi_T']):.0f} N/m" in out
    printed = re.findall(r"^([MBK])([12])([12]) = (\S+) \+- (\S+) .*\(true (\S+)\)$", out, flags=re.M)
    assert len(printed) == 12
    for sym, i, j, value, half, true in printed:
        name = dict(M="mass", B="damping", K="stiffness")[sym]
        ij = int(i) - 1, int(j) - 1
        assert float(value) == pytest.approx(float(np.asarray(getattr(fit, name))[ij]), rel=1e-2)
        assert float(half) == pytest.approx(1.96 * float(np.asarray(getattr(fit, name + "_se"))[ij]), rel=1e-1)
        assert float(true) == pytest.approx(float(np.asarray(getattr(arm, name))[ij]), rel=1e-2)
    jax.config.update("jax_enable_x64", True)
