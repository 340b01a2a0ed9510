"""A lab's own kind with no package change: the Stribeck law of docs/examples/stribeck_law.py
through ``sweep.py --config --import``, its slope by ``jax.jvp`` (the default) against finite
differences and a hand-written slope, ``aj.per_joint`` fields, ``__check_init__``, the
``armimp_jax.kinds`` entry-point group, and ``--import`` refusals in one line."""

import importlib.metadata
import pathlib
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest

import armimp_jax as aj
from armimp_jax import presets
from armimp_jax._model import kinds
from armimp_jax._model.controllers import CONTROLLER_KINDS
from armimp_jax._model.friction import FRICTION_KINDS, friction_kind
from armimp_jax.study.runs import cli

ROOT = pathlib.Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "docs" / "examples" / "stribeck_law.py"
CONFIG = ROOT / "docs" / "examples" / "stribeck.toml"


@pytest.fixture(autouse=True)
def own_registries(monkeypatch):
    """The kinds a test here defines register in copies of the registries, dropped after it, so
    no later test on the worker sees them (their modules leave ``sys.modules`` too)."""
    for registry in (CONTROLLER_KINDS, FRICTION_KINDS):
        monkeypatch.setattr(registry, "_kinds", dict(registry._kinds))
    yield
    for name in [m for m in sys.modules if m.startswith("armimp_jax_kinds_") or m == "lab_kinds_ep"]:
        del sys.modules[name]


@pytest.fixture
def stribeck():
    (name,) = cli.import_kinds([str(EXAMPLE)], "test")
    return friction_kind(name)


def _sweep(*args, out):
    cmd = [sys.executable, "sweeps/sweep.py", "--config", str(CONFIG), *args, "--out", str(out)]
    return subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, timeout=300)


@pytest.mark.slow  # 15 s: the script's own process (its compile); the default tier imports the file in-process
def test_a_labs_stribeck_law_sweeps_from_a_config_with_no_package_change(tmp_path):
    run = _sweep("--import", str(EXAMPLE), out=tmp_path / "out")
    assert run.returncode == 0, run.stderr
    rows = pd.read_csv(tmp_path / "out" / "trials.csv")
    assert list(rows["friction"]) == ["stribeck", "stribeck"] and list(rows["tau_c"]) == [0.05, 0.2]
    assert (rows["tau_s"] == 0.3).all() and np.isfinite(rows["phi_T"]).all()
    # without the file the kind is unknown, and the message says how to load it
    run = _sweep(out=tmp_path / "other")
    assert run.returncode == 2
    assert "unknown friction type 'stribeck'" in run.stderr and "--import FILE.py" in run.stderr
    assert len(run.stderr.strip().splitlines()) == 1


def test_the_default_slope_is_the_torques_derivative(stribeck):
    law = stribeck(tau_c=0.1, tau_s=0.25, v_st=0.02, eps=1e-3).joint(0)
    v = jnp.array([-0.3, -0.01, -1e-4, 0.0, 2e-4, 0.015, 0.5])
    h = 1e-7
    central = (law.static_torque(v + h) - law.static_torque(v - h)) / (2 * h)
    np.testing.assert_allclose(law.static_slope(v), central, rtol=1e-6, atol=1e-6)
    # the same default on a shipped law gives its hand-written slope
    cv = aj.CoulombViscous(0.06, 0.0025).joint(1)
    jvp = aj.AbstractFriction.static_slope(cv, v)
    np.testing.assert_allclose(jvp, cv.static_slope(v), rtol=1e-13, atol=1e-12)


def test_per_joint_fields_broadcast_and_check_init_refuses_in_one_line(stribeck):
    law = stribeck(tau_c=0.1, tau_s=(0.2, 0.3))
    assert law.tau_c.shape == (2,) and law.tau_c.dtype == np.float64 and law.tau_s.tolist() == [0.2, 0.3]
    assert law.eps.tolist() == [1e-3, 1e-3]
    with pytest.raises(ValueError, match=r"must be a scalar or shape \(2,\), got shape \(3,\)"):
        stribeck(tau_c=(0.1, 0.2, 0.3))
    with pytest.raises(ValueError, match="Stribeck: tau_s must be 0 or >= tau_c"):
        stribeck(tau_c=0.2, tau_s=0.1)
    with pytest.raises(ValueError, match="Stribeck: eps must be > 0 rad/s"):
        stribeck(tau_c=0.2, eps=0.0)
    # built inside a trace: the ranges ride into the program (checked when it runs), the rule across fields waits
    jax.jit(lambda c: stribeck(tau_c=c).tau_c)(0.1)


def test_the_law_simulates_under_rk4_and_the_imex_integrators(stribeck):
    f = aj.perturbation(jax.random.key(3), 500, 10.0)
    trial = aj.make_trial(aj.PD(), arm=presets.arm(2), friction=stribeck(tau_c=0.1, tau_s=0.2))
    xs = [
        aj.simulate(trial, f, numerics=aj.Numerics(solver=solver, substeps=20)).x
        for solver in (aj.solvers.RK4(), aj.solvers.ARK3())
    ]
    assert all(np.isfinite(x).all() for x in xs)
    np.testing.assert_allclose(xs[0], xs[1], atol=2e-6)


def test_an_installed_package_of_kinds_is_found_through_its_entry_point(tmp_path, monkeypatch):
    (tmp_path / "lab_kinds_ep.py").write_text(
        "from typing import ClassVar\nimport armimp_jax as aj\n\n\n"
        "class Sticky(aj.AbstractFriction):\n"
        "    kind: ClassVar[str] = 'ep_sticky'\n    UNITS: ClassVar[dict] = dict(b='N m s/rad')\n"
        "    b: object = aj.per_joint(0.01)\n\n"
        "    def viscous_coefficient(self):\n        return self.b\n\n"
        "    def without_coulomb(self):\n        return self\n\n"
        "    def has_coulomb(self):\n        return False\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    point = importlib.metadata.EntryPoint("lab", "lab_kinds_ep", kinds.ENTRY_POINTS)
    monkeypatch.setattr(kinds, "_loaded_entry_points", [])
    monkeypatch.setattr(
        importlib.metadata, "entry_points", lambda group: [point] if group == kinds.ENTRY_POINTS else []
    )
    assert friction_kind("ep_sticky").__name__ == "Sticky"


def test_two_files_of_one_name_stay_two_and_one_file_imported_twice_is_one_kind(tmp_path, monkeypatch):
    for lab in ("a", "b"):
        (tmp_path / lab).mkdir()
        (tmp_path / lab / "kinds.py").write_text(
            "from typing import ClassVar\nimport armimp_jax as aj\n\n\n"
            f"class Law(aj.AbstractFriction):\n    kind: ClassVar[str] = 'law_{lab}'\n"
            "    UNITS: ClassVar[dict] = dict(b='N m s/rad')\n    b: object = aj.per_joint(0.01)\n\n"
            "    def viscous_coefficient(self):\n        return self.b\n\n"
            "    def without_coulomb(self):\n        return self\n\n"
            "    def has_coulomb(self):\n        return False\n"
        )
    files = [str(tmp_path / lab / "kinds.py") for lab in ("a", "b")]
    assert cli.import_kinds(files, "test") == ("law_a", "law_b")
    # the same file imported as a module too (a lab's own Python, then a script's --import)
    monkeypatch.syspath_prepend(str(tmp_path / "a"))
    monkeypatch.delitem(sys.modules, "kinds", raising=False)
    __import__("kinds")
    assert friction_kind("law_a").__module__ == "kinds"
    del sys.modules["kinds"]


def test_a_broken_entry_point_is_named_and_the_others_still_load(tmp_path, monkeypatch):
    (tmp_path / "lab_kinds_ep.py").write_text(
        "from typing import ClassVar\nimport armimp_jax as aj\n\n\n"
        "class Good(aj.AbstractFriction):\n    kind: ClassVar[str] = 'ep_good'\n"
        "    UNITS: ClassVar[dict] = dict(b='N m s/rad')\n    b: object = aj.per_joint(0.01)\n\n"
        "    def viscous_coefficient(self):\n        return self.b\n\n"
        "    def without_coulomb(self):\n        return self\n\n"
        "    def has_coulomb(self):\n        return False\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    points = [
        importlib.metadata.EntryPoint("broken", "no_such_lab_module", kinds.ENTRY_POINTS),
        importlib.metadata.EntryPoint("lab", "lab_kinds_ep", kinds.ENTRY_POINTS),
    ]
    monkeypatch.setattr(kinds, "_loaded_entry_points", [])
    monkeypatch.setattr(importlib.metadata, "entry_points", lambda group: points if group == kinds.ENTRY_POINTS else [])
    assert friction_kind("ep_good").__name__ == "Good"
    with pytest.raises(ValueError, match=r"entry points that failed to load: broken \(no_such_lab_module\)"):
        friction_kind("lugr")


def test_bad_imports_are_refused_in_one_line(tmp_path, capsys):
    with pytest.raises(SystemExit):
        cli.check_imports([str(tmp_path / "missing.py")], "prog")
    (tmp_path / "plain.py").write_text("x = 1\n")
    (tmp_path / "broken.py").write_text("raise RuntimeError('the lab file fails')\n")
    with pytest.raises(SystemExit):
        cli.import_kinds([str(tmp_path / "plain.py")], "prog")
    with pytest.raises(SystemExit):
        cli.import_kinds([str(tmp_path / "broken.py")], "prog")
    lines = capsys.readouterr().err.strip().splitlines()
    assert lines == [
        f"prog: error: --import {tmp_path / 'missing.py'}: no such file",
        f"prog: error: --import {tmp_path / 'plain.py'} defines no controller or friction kind"
        " (a kind names itself: kind = '...')",
        f"prog: error: --import {tmp_path / 'broken.py'}: RuntimeError: the lab file fails",
    ]
    assert not [m for m in sys.modules if m.startswith("armimp_jax_kinds_broken")]


def test_the_guides_examples_run_and_their_slope_is_the_closed_form():
    # docs/extending.md's two classes, as a reader copies them
    blocks = (ROOT / "docs" / "extending.md").read_text().split("```python\n")[1:3]
    space = {}
    exec(compile("\n".join(b.split("```")[0] for b in blocks), "extending.md", "exec"), space)
    law = space["SmoothCoulomb"](tau_c=0.2).joint(0)
    v = jnp.linspace(-0.05, 0.05, 11)
    closed = 0.2 * 0.005**2 / (v * v + 0.005**2) ** 1.5
    np.testing.assert_allclose(law.static_slope(v), closed, rtol=1e-12)
    with pytest.raises(ValueError, match="SmoothCoulomb: eps must be > 0 rad/s, got"):
        space["SmoothCoulomb"](tau_c=0.2, eps=-1.0)
    trial = aj.make_trial(space["Damper"](), arm=presets.arm(2), friction=space["SmoothCoulomb"](tau_c=0.05))
    assert np.isfinite(aj.simulate(trial, aj.perturbation(jax.random.key(1), 300, 10.0)).x).all()


@pytest.fixture
def joint_impedance():
    (name,) = cli.import_kinds([str(ROOT / "docs" / "examples" / "joint_impedance.py")], "test")
    return aj.kinds.controller_kind(name)


@pytest.mark.slow  # 10 s: four simulations and a bound
def test_a_joint_space_law_is_the_cartesian_pd_of_its_jacobian_for_small_motions(joint_impedance):
    # K = J^-T K_q J^-1, B = J^-T B_q J^-1 at q0: the two loops differ at second order in the motion
    law = joint_impedance()
    trial = aj.make_trial(law, arm=presets.arm(2), friction=aj.NO_FRICTION)
    inv = np.linalg.inv(np.asarray(aj.linear.jacobian(trial.q0, trial.robot)))
    pd = aj.PD(kp=inv.T @ np.asarray(law.k_q) @ inv, kv=inv.T @ np.asarray(law.b_q) @ inv)
    cartesian = aj.make_trial(pd, arm=presets.arm(2), friction=aj.NO_FRICTION)
    rel = []
    for peak in (0.5, 2.0):
        f = aj.perturbation(jax.random.key(4), 3000, peak)
        a, b = aj.simulate(trial, f), aj.simulate(cartesian, f)
        motion = np.abs(np.asarray(a.x) - np.asarray(trial.x0)).max()
        rel.append(np.abs(np.asarray(a.x) - np.asarray(b.x)).max() / motion)
    assert rel[0] < 2e-3 and 2.5 < rel[1] / rel[0] < 6.0  # first order in the amplitude (ratio 4)
    # the bound linearises through its step like any kind's
    sensed = aj.make_trial(
        law, arm=presets.arm(2), friction=aj.NO_FRICTION, sensors=aj.Sensors(force_noise=0.05, encoder_counts=2**18)
    )
    bound = aj.crlb(sensed, aj.perturbation(jax.random.key(3), 2000, 2.25), free=("arm.stiffness",))
    assert np.all(np.isfinite(np.asarray(bound.covariance))) and np.all(np.diag(np.asarray(bound.covariance)) > 0)


def test_a_joint_space_laws_replay_reads_the_joints_of_the_recorded_hand(joint_impedance):
    from armimp_jax._identification.auxiliary import replay_command

    trial = aj.make_trial(joint_impedance(), arm=presets.arm(2), friction=aj.NO_FRICTION)
    f = aj.perturbation(jax.random.key(5), 2000, 2.25)
    sim = aj.simulate(trial, f)
    replayed = np.asarray(replay_command(trial, f, sim.x, sim.fh))
    command = np.asarray(sim.fu) - np.asarray(f)  # the law's own part of F_u
    assert np.abs(replayed - np.asarray(sim.fu)).max() < 0.05 * np.abs(command).max()
    with pytest.raises(ValueError, match="cannot follow a moving arm"):
        reach = aj.MinimumJerk(start=trial.x0, end=np.asarray(trial.x0) + [0.0, 0.1], onset=0.2, duration=0.8)
        arm = presets.arm(2)
        aj.make_trial(
            joint_impedance(), arm=aj.Arm(arm.mass, arm.damping, arm.stiffness, reach), friction=aj.NO_FRICTION
        )


def test_the_kinds_defined_here_are_gone_after_their_tests():
    assert not {"stribeck", "smooth_coulomb", "ep_sticky", "ep_good", "law_a", "law_b"} & set(FRICTION_KINDS.names())
    assert not {"damper", "joint_impedance"} & set(CONTROLLER_KINDS.names())
