"""The README's two commands are the ones CI and users run."""

import json
import os
import pathlib
import re
import subprocess
import sys

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


# Runs in a process of its own, as a user runs it: the example's ``aj.runtime.configure()`` sets
# up that process (on an AVX-512 host it adds 512-bit vectors to XLA_FLAGS), not the pytest worker.
CHILD = r"""
import json, pathlib, re, sys
import numpy as np
code = re.findall(r"```python\n(.*?)```", pathlib.Path(sys.argv[1]).read_text(), flags=re.S)[0]
scope = {}
exec(compile(code, "README.md", "exec"), scope)
est, arm, fit = scope["est"], scope["arm"], scope["fit"]
z = np.asarray(est.Z)
names = ("mass", "damping", "stiffness")
seen = dict(
    f=np.asarray(est.f).tolist(), z=[z.real.tolist(), z.imag.tolist()], phi_T=float(scope["phi_T"]),
    arm={n: np.asarray(getattr(arm, n)).tolist() for n in names},
    fit={n: np.asarray(getattr(fit, n)).tolist() for n in names},
    interval={n: [np.asarray(v).tolist() for v in fit.interval(n)] for n in names},
    vaf_overall=float(fit.vaf_overall), warnings=list(fit.warnings), sims_x=list(scope["sims"].x.shape),
)
print(sys.argv[2] + json.dumps(seen))
"""
MARKER = "README-EXAMPLE-SAW: "


def _run_readme_example() -> tuple[str, dict]:
    """The README's quick start, verbatim, in a fresh Python (``-W error``: a warning fails it, as
    in the suite): what it printed, and what it computed."""
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}  # a user's fresh process
    run = subprocess.run(
        [sys.executable, "-W", "error", "-c", CHILD, str(ROOT / "README.md"), MARKER],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
    )
    assert run.returncode == 0, run.stderr[-3000:]
    printed, _, seen = run.stdout.rpartition(MARKER)
    return printed, json.loads(seen)


def test_readme_library_example_runs():
    """The README's quick start, verbatim: a custom arm and friction, noise, a fit, a batch, a
    gradient; it prints phi_T and, at the defaults, every element of M, B, K with its 95% interval
    (each holding the truth here) and the fit's warnings."""
    out, seen = _run_readme_example()
    # phi_T as the paper defines it (eqs. 1-2), computed here: the mean over the bins of the largest
    # singular value of Z_h(j 2 pi f) - Z_hat(f), with Z_h = K + j w B - w^2 M of the README's arm
    arm = {name: np.asarray(v) for name, v in seen["arm"].items()}
    z_hat = np.asarray(seen["z"][0]) + 1j * np.asarray(seen["z"][1])
    s = 2j * np.pi * np.asarray(seen["f"])[:, None, None]
    z_h = arm["mass"] * s**2 + arm["damping"] * s + arm["stiffness"]
    phi_t = np.linalg.norm(z_h - z_hat, 2, axis=(1, 2)).mean()
    assert seen["phi_T"] == pytest.approx(phi_t, rel=1e-12)
    assert phi_t < 0.1 * np.linalg.norm(z_h, 2, axis=(1, 2)).mean()  # within claim (a)'s 10% of mean |Z_h|
    assert seen["sims_x"] == [3, 12_000, 2]
    np.testing.assert_allclose(seen["fit"]["mass"], arm["mass"], atol=0.15)  # [kg]
    assert seen["vaf_overall"] > 95.0
    assert f"phi_T = {seen['phi_T']:.0f} N/m" in out
    # fit.summary() with no option beyond the defaults: twelve 95% intervals, then the warnings
    printed = re.findall(r"^([MBK])([xy])([xy]) \[[^]]+\]\s+(\S+)\s+\[(\S+), (\S+)\]$", out, flags=re.M)
    assert len(printed) == 12
    for sym, i, j, value, low, high in printed:
        name = dict(M="mass", B="damping", K="stiffness")[sym]
        ij = "xy".index(i), "xy".index(j)
        lo, hi = (np.asarray(v) for v in seen["interval"][name])
        assert float(value) == pytest.approx(np.asarray(seen["fit"][name])[ij], rel=1e-3)
        assert (float(low), float(high)) == pytest.approx((lo[ij], hi[ij]), rel=1e-3, abs=1e-3)
        assert float(low) <= arm[name][ij] <= float(high), (sym, i, j)  # they hold here
    assert [line[len("WARNING: ") :] for line in out.splitlines() if line.startswith("WARNING: ")] == seen["warnings"]
    assert not any(w.startswith("implausible") for w in seen["warnings"])  # the plausibility guard is silent here
