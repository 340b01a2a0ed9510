"""Gradients of phi_T w.r.t. Mhat (both modes vs finite differences), the tuner's guard, and its
saved state (one checked file that matches its settings)."""

import importlib.util
import json
import os
import pathlib
import re
import shlex
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

import armimp_jax as aj
from armimp_jax import Welch
from armimp_jax import paper as presets
from armimp_jax._batch import make_mesh
from armimp_jax.paper import mhat_experiment as paper_tune
from armimp_jax.study.design import tuning as tune
from armimp_jax.study.runs import engine
from armimp_jax.study.runs import results as res
from armimp_jax.study.runs.runfolder import StudyRun

WELCH = Welch(512, 384)
ROOT = pathlib.Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "sweeps" / "tune_mhat.py"


def strict_loads(text):
    def refuse(token):
        raise AssertionError(f"non-standard JSON constant {token}")

    return json.loads(text, parse_constant=refuse)


NUM = paper_tune.training_numerics(4)  # the tuner's: "grad" kernel, a carry per substep on the tape


@pytest.fixture(scope="module")
def short_batch():
    """Friction 0 and 2 at location 1: 1.6 s records, 4 substeps (a few seconds, reduced nperseg)."""
    params, f_delta = paper_tune.training_batch((0, 2), (1,), (0,), seconds=1.6)
    return params, f_delta


def _per_trial_losses(theta, params, f_delta):
    p = tune.with_mhat(params, tune.mhat_from_theta(theta, "diagonal"))
    losses, _ = jax.vmap(lambda t, f: tune.trial_loss(t, f, WELCH, 0.0, NUM))(p, f_delta)
    return losses


@pytest.mark.slow  # about 16 s cold: phi's gradient by finite differences (test_trial checks it fast)
def test_gradient_matches_finite_differences_at_friction_0_and_2(short_batch):
    params, f_delta = short_batch
    theta = tune.theta_from_mhat(0.4 * np.eye(2), "diagonal")
    # the losses and their Jacobian (rows: friction 0, friction 2) from one program
    both = jax.jit(lambda *a: (_per_trial_losses(*a), jax.jacfwd(_per_trial_losses)(*a)))
    jac = both(theta, params, f_delta)[1]
    assert np.all(np.isfinite(jac)) and np.all(jac != 0)

    def f(*a):
        return both(*a)[0]

    eps = 1e-3
    fd = np.stack(
        [(f(theta + eps * e, params, f_delta) - f(theta - eps * e, params, f_delta)) / (2 * eps) for e in jnp.eye(2)],
        axis=1,
    )
    np.testing.assert_allclose(jac, fd, rtol=2e-5)


@pytest.mark.slow  # the fast suite checks the gradient against finite differences
def test_forward_and_reverse_modes_agree(short_batch):
    params, f_delta = short_batch
    theta = tune.theta_from_mhat(np.array([[0.4, 0.05], [0.05, 0.3]]), "full")
    kw = dict(parameterisation="full", welch=WELCH, numerics=NUM)
    (v_f, aux_f), g_f = tune.value_and_grad_fn(mode="forward", **kw)(theta, params, f_delta)
    (v_r, aux_r), g_r = tune.value_and_grad_fn(mode="reverse", **kw)(theta, params, f_delta)
    # the two programs fuse the primal differently: its last bits may move
    np.testing.assert_allclose(v_f, v_r, rtol=1e-13)
    assert np.all(np.isfinite(g_r))
    np.testing.assert_allclose(g_f, g_r, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(aux_f.phi_T, aux_r.phi_T, rtol=1e-13)


@pytest.mark.slow  # the grad kernel is checked fast against finite differences and by a tuning run
def test_grad_and_fast_kernels_give_the_same_gradient(short_batch):
    # The tuner's "grad" kernel shares stage values for reverse mode; the maths is "fast"'s.
    params, f_delta = short_batch
    assert NUM.kernel == "grad"
    kw = dict(parameterisation="diagonal", welch=WELCH, mode="reverse")
    theta = tune.theta_from_mhat(0.4 * np.eye(2), "diagonal")
    (v_g, _), g_g = tune.value_and_grad_fn(**kw, numerics=NUM)(theta, params, f_delta)
    fast = paper_tune.training_numerics(4, kernel="fast")
    (v_f, _), g_f = tune.value_and_grad_fn(**kw, numerics=fast)(theta, params, f_delta)
    np.testing.assert_allclose(v_g, v_f, rtol=1e-12)
    np.testing.assert_allclose(g_g, g_f, rtol=1e-9)


@pytest.mark.slow  # about 13 s cold
@pytest.mark.parametrize("kernel", [pytest.param("fast", marks=pytest.mark.slow), "grad"])
def test_no_nan_in_the_gradient_at_friction_0(kernel):
    params = aj.batch.stack_trials([presets.trial("imbic", 0, loc) for loc in (1, 3)])
    f_delta = jnp.asarray(paper_tune.seed_perturbations(0, [5, 6], 1200))
    numerics = paper_tune.training_numerics(3, kernel=kernel)
    vg = tune.value_and_grad_fn(parameterisation="diagonal", welch=Welch(512, 256), mode="reverse", numerics=numerics)
    (_, _), g = vg(jnp.log(jnp.array([0.25, 0.25])), params, f_delta)
    assert np.all(np.isfinite(g))


@pytest.mark.parametrize("kind", ["diagonal", "full"])
def test_parameterisation_is_spd_and_invertible(kind):
    m = np.array([[0.6, 0.1], [0.1, 0.3]]) if kind == "full" else np.diag([0.6, 0.3])
    theta = tune.theta_from_mhat(m, kind)
    np.testing.assert_allclose(tune.mhat_from_theta(theta, kind), m, rtol=1e-14)
    for t in np.random.default_rng(0).normal(size=(20, theta.shape[0])) * 3:
        mh = np.asarray(tune.mhat_from_theta(jnp.asarray(t), kind))
        np.testing.assert_allclose(mh, mh.T)
        assert np.all(np.linalg.eigvalsh(mh) > 0)
    with pytest.raises(ValueError, match="symmetric positive definite"):
        tune.theta_from_mhat(-np.eye(2), "full")


@pytest.mark.slow  # about 11 s cold: a tuning run (its divergence guards stay fast)
def test_short_tuning_run_lowers_the_loss_from_a_poor_start():
    params, f_delta = paper_tune.training_batch((2,), (1,), (0,), seconds=1.6)
    config = tune.TuneConfig(learning_rate=0.3, iterations=4, numerics=NUM)
    logs = []
    state = tune.tune(
        tune.theta_from_mhat(1.5 * np.eye(2), "diagonal"), params, f_delta, WELCH, config, log=logs.append
    )
    losses = state.history.loss[state.history.accepted]
    assert len(losses) >= 3 and losses[-1] < losses[0]
    assert np.all(np.diag(tune.mhat_from_theta(state.theta, "diagonal")) < 1.5)


@pytest.mark.slow  # 18 s cold (the suite's budget)
def test_divergence_guard_on_unstable_start_and_on_unstable_steps(tmp_path):
    params, f_delta = paper_tune.training_batch((1,), (1,), (0,), seconds=1.6)
    logs = []
    # an unstable start (far above 2 M_x): shrunk until stable, and said so
    config = tune.TuneConfig(learning_rate=0.1, iterations=1, numerics=NUM)
    state = tune.tune(
        tune.theta_from_mhat(40.0 * np.eye(2), "diagonal"), params, f_delta, WELCH, config, log=logs.append
    )
    assert any(r.get("event") == "start diverged" for r in logs)
    assert np.isfinite(state.value)
    # steps that land on unstable gains (a deliberately huge ascent step) are rejected, not taken
    logs.clear()
    config = tune.TuneConfig(learning_rate=-6.0, iterations=2, numerics=NUM)
    settings = dict(tuner=tune.config_settings(config), problem="friction 1, location 1, seed 0")
    path = tmp_path / "state.npz"
    saved = []
    state = tune.tune(
        tune.theta_from_mhat(0.3 * np.eye(2), "diagonal"),
        params,
        f_delta,
        WELCH,
        config,
        log=logs.append,
        on_iteration=lambda st: saved.append(tune.save_state(path, st, settings)),
    )
    rejected = [r for r in logs if str(r.get("event", "")).startswith("rejected")]
    assert rejected and state.rejected >= 1 and state.step_scale < 1.0
    assert np.all(np.isfinite(np.asarray(state.theta))) and np.isfinite(state.value)
    assert rejected[-1] == state.history.record(-1) and not state.history.accepted[-1]
    # ...every iteration, rejected ones too, was saved, and the state resumes where it stopped
    assert len(saved) == 1 + state.iteration
    again = tune.load_state(path, settings, config)
    jax.tree.map(np.testing.assert_array_equal, again, state)  # NaN (rejected rows) equal to NaN


SHARDED_GRADIENT = """
import json, logging, re
from armimp_jax.runtime import configure
configure(host_devices=3)
import jax, numpy as np
from armimp_jax import Welch
from armimp_jax.study.design import tuning as tune
from armimp_jax.paper import mhat_experiment as paper_tune
params, f_delta = paper_tune.training_batch((0, 2), (1,), (0,), seconds=1.6)
NUM = paper_tune.training_numerics(4)
vg = tune.value_and_grad_fn(parameterisation="diagonal", welch=Welch(512, 384), mode="reverse", numerics=NUM)
theta = tune.theta_from_mhat(0.4 * np.eye(2), "diagonal")
out = {}
for name, batch in (("one", (params, f_delta, None)), ("two", tune.place_batch(params, f_delta))):
    (value, aux), grad = vg(theta, *batch[:2])
    devices = len(batch[0].q0.sharding.device_set)
    placed = None if batch[2] is None else batch[2].size
    out[name] = dict(value=float(value), grad=np.asarray(grad).tolist(), devices=devices, placed=placed)
# not padded: a batch spans the largest number of devices that divides it
for n_trials in (1, 3):
    batch = paper_tune.training_batch((0,), (1,), tuple(range(n_trials)), seconds=1.6)
    placed = tune.place_batch(*batch)[2]
    out[f"placed {n_trials}"] = None if placed is None else placed.size
# a short tuning run on two devices compiles its gradient once, not again at the first step
compiled = []
class Compiles(logging.Handler):
    def emit(self, record):
        if re.match(r"Compiling \\S*loss", record.getMessage()):
            compiled.append(record.getMessage())
logging.getLogger("jax").addHandler(Compiles())
config = tune.TuneConfig(learning_rate=0.1, iterations=2, numerics=NUM)
logs = []
with jax.log_compiles():
    state = tune.tune(theta, params, f_delta, Welch(512, 384), config, log=logs.append)
out["tune"] = dict(compiles=len(compiled), steps=state.iteration, first=logs[0])
print(json.dumps(out))
"""

# Subprocesses that set their own device count: the parent's XLA flags and platform stay out.
CPU_ENV = dict(os.environ, XLA_FLAGS="", JAX_PLATFORMS="cpu")


@pytest.mark.slow  # sharded forward runs are checked fast in test_plant
def test_training_batch_sharded_over_devices_gives_the_same_gradient():
    proc = subprocess.run(
        [sys.executable, "-c", SHARDED_GRADIENT], capture_output=True, text=True, env=CPU_ENV, timeout=600
    )
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert out["one"]["devices"] == 1 and out["two"]["devices"] == 2 and out["two"]["placed"] == 2
    assert out["placed 1"] is None and out["placed 3"] == 3
    assert out["tune"]["first"] == {"event": "training batch", "trials": 2, "devices": 2}
    assert out["tune"]["steps"] == 2 and out["tune"]["compiles"] == 1
    # Round-off apart: the "grad" kernel's last bits depend on the per-device batch (measured
    # 1.4e-13 relative in the loss), and the mean and gradient are summed across devices.
    np.testing.assert_allclose(out["two"]["value"], out["one"]["value"], rtol=1e-11)
    np.testing.assert_allclose(out["two"]["grad"], out["one"]["grad"], rtol=1e-9)


def test_place_batch_on_one_device_leaves_the_batch_alone(short_batch):
    params, f_delta = short_batch
    placed = tune.place_batch(params, f_delta, mesh=make_mesh(jax.devices()[:1]))
    assert placed[0] is params and placed[1] is f_delta and placed[2] is None
    with pytest.raises(ValueError, match="inconsistent batch sizes"):
        tune.place_batch(params, f_delta[:1])


@pytest.mark.slow  # the fast suite checks the gradient against finite differences
def test_substep_and_period_checkpoints_give_the_same_gradient(short_batch):
    # What reverse mode keeps changes the work, not the maths.
    params, f_delta = short_batch
    assert NUM.checkpoint == "substep"  # the tuner's
    kw = dict(parameterisation="full", welch=WELCH, mode="reverse")
    theta = tune.theta_from_mhat(np.array([[0.4, 0.05], [0.05, 0.3]]), "full")
    (v_s, _), g_s = tune.value_and_grad_fn(**kw, numerics=NUM)(theta, params, f_delta)
    period = paper_tune.training_numerics(4, checkpoint="period")
    (v_p, _), g_p = tune.value_and_grad_fn(**kw, numerics=period)(theta, params, f_delta)
    np.testing.assert_allclose(v_s, v_p, rtol=1e-13)
    np.testing.assert_allclose(g_s, g_p, rtol=1e-10)


def test_unknown_mode_and_parameterisation_are_rejected():
    with pytest.raises(ValueError, match="unknown gradient mode 'central'; allowed: 'forward', 'reverse'"):
        tune.value_and_grad_fn(parameterisation="diagonal", welch=WELCH, mode="central")
    with pytest.raises(ValueError, match="unknown parameterisation 'lower'; allowed: 'diagonal', 'full'"):
        tune.value_and_grad_fn(parameterisation="lower", welch=WELCH)


@pytest.mark.slow  # a full quick tuning run; --help and the loop are checked fast
def test_tune_script_quick_produces_its_outputs(tmp_path):
    root = pathlib.Path(__file__).resolve().parents[1]
    proc = subprocess.run(
        [
            sys.executable,
            str(root / "sweeps" / "tune_mhat.py"),
            "--quick",
            "--iterations",
            "2",
            "--compare",
            "0.25",
            "--out",
            str(tmp_path),
        ],
        capture_output=True,
        text=True,
        env=dict(CPU_ENV, XLA_FLAGS="--xla_force_host_platform_device_count=2"),
        timeout=900,
    )
    assert proc.returncode == 0, proc.stderr
    mhat = np.array(strict_loads((tmp_path / "mhat.json").read_text())["mhat"])
    assert mhat.shape == (2, 2) and np.all(np.linalg.eigvalsh(mhat) > 0)
    for name in ("loss_curve.png", "comparison.md", "comparison.json", "trials/iteration-0002.npz"):
        assert (tmp_path / name).stat().st_size > 0, name
    assert strict_loads((tmp_path / "comparison.json").read_text())["best"] in ("tuned", "0.25 I")
    assert "| tuned |" in (tmp_path / "comparison.md").read_text()
    state = res.load_record(tmp_path / "trials" / "iteration-0002.npz")
    assert state.settings["tuner"]["parameterisation"] == "diagonal" and state.settings["iteration"] == 2
    assert strict_loads((tmp_path / "run.json").read_text())["options"]["quick"]
    # two host devices (runtime.configure keeps a count that is set): 8 training trials span both
    assert '"event": "training batch", "trials": 8, "devices": 2' in proc.stdout


# --- the saved state: a checked pytree that matches its settings -----------------------------


@pytest.fixture(scope="module")
def script():
    """sweeps/tune_mhat.py as a module (its top level imports the standard library only)."""
    spec = importlib.util.spec_from_file_location("tune_mhat", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _fake_state(parameterisation="diagonal", n_trials=2):
    """A TuneState after one accepted and one rejected step, built without simulating."""
    theta = tune.theta_from_mhat(0.25 * np.eye(2), parameterisation)
    grad = jnp.full(theta.shape, 0.5)
    opt_state = optax.adam(0.1).update(grad, optax.adam(0.1).init(theta), theta)[1]
    history = (
        tune.History.empty(n_trials)
        .append(iteration=0, accepted=True, loss=800.0, grad_norm=1.0, mhat=0.25 * np.eye(2), step_scale=1.0,
                time_s=2.0, phi_T=[700.0, 900.0])
        .append(iteration=1, accepted=False, mhat=9 * np.eye(2), step_scale=0.5, time_s=0.5)
    )  # fmt: skip
    return tune.TuneState(theta, opt_state, grad, 800.0, 1, 0.5, 1, history)


def test_state_is_a_pytree_saved_in_one_checked_file(tmp_path):
    state, config = _fake_state(), tune.TuneConfig()
    settings = dict(tuner=tune.config_settings(config), training="test")
    path = tmp_path / "state.npz"
    tune.save_state(path, state, settings)
    assert [p.name for p in tmp_path.iterdir()] == ["state.npz"]
    again = tune.load_state(path, settings, config)
    assert jax.tree.structure(again) == jax.tree.structure(state)
    jax.tree.map(np.testing.assert_array_equal, again, state)
    assert again.history.records() == state.history.records()
    assert [r["event"] for r in again.history.records()] == ["start", "rejected: diverged or non-finite"]
    # iterations is not a setting: a run may be resumed with a larger budget
    assert tune.config_settings(tune.TuneConfig(iterations=99)) == tune.config_settings(config)


def test_state_with_other_settings_is_refused_in_one_line(tmp_path):
    # The defect: resuming with another --parameterisation ran, rejected every step and
    # printed a NaN table.
    path = tmp_path / "state.npz"
    config = tune.TuneConfig()
    tune.save_state(path, _fake_state(), dict(tuner=tune.config_settings(config)))
    full = tune.TuneConfig(parameterisation="full", learning_rate=0.3)
    with pytest.raises(res.ResultsError) as err:
        tune.load_state(path, dict(tuner=tune.config_settings(full)), full)
    message = str(err.value)
    assert "\n" not in message and str(path) in message
    assert "tuner.learning_rate=0.1 (you asked 0.3), tuner.parameterisation=diagonal (you asked full)" in message
    with pytest.raises(ValueError, match="the state has 2 parameters; parameterisation 'full' has 3"):
        tune.tune(None, None, None, WELCH, full, state=_fake_state())


def test_torn_or_altered_state_is_named(tmp_path):
    path = tmp_path / "state.npz"
    config = tune.TuneConfig()
    settings = dict(tuner=tune.config_settings(config))
    tune.save_state(path, _fake_state(), settings)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 3])
    with pytest.raises(res.ResultsError, match=re.escape(f"{path}: unreadable, truncated")):
        tune.load_state(path, settings, config)
    path.write_bytes(data)
    with np.load(path) as d:
        entries = {k: d[k] for k in d.files}
    entries["theta"] = entries["theta"] + 1.0
    np.savez(path, **entries)
    with pytest.raises(res.ResultsError, match="checksum mismatch"):
        tune.load_state(path, settings, config)


def test_nan_is_never_the_lowest_candidate():
    table = {
        "tuned": np.full((1, 2, 1), np.nan),
        "0.25 I": np.full((1, 2, 1), 700.0),
        "huge": np.full((1, 2, 1), 1.0),
        "_diverged": ["tuned", "huge"],
    }
    assert paper_tune.best_candidate(table) == "0.25 I"
    evals = dict(seconds=2.5, substeps=20, welch=WELCH)
    md = paper_tune.comparison_markdown(table, 0.25 * np.eye(2), locations=(1, 2), evals=evals, seeds=(0,))
    assert "Lowest mean phi_T: **0.25 I**" in md and "| tuned (diverged) | — | — | — |" in md
    table["0.25 I"][0, 0, 0] = np.nan
    assert paper_tune.best_candidate(table) is None
    md = paper_tune.comparison_markdown(table, 0.25 * np.eye(2), locations=(1, 2), evals=evals, seeds=(0,))
    assert "Lowest mean phi_T: none" in md


def test_resume_hint_is_the_full_command(script):
    options = script.DEFAULTS | dict(lr=0.3, parameterisation="full", frictions=[2], quick=True)
    line = script.command_line(pathlib.Path("out dir"), options)
    argv = shlex.split(line)
    assert argv[:4] == ["python", "sweeps/tune_mhat.py", "--resume", "out dir"]
    assert script.explicit(script.parse(argv[2:])) == options


def _run_tune_script(*args):
    return subprocess.run(
        [sys.executable, str(SCRIPT), *args], capture_output=True, text=True, env=CPU_ENV, timeout=300
    )


def test_script_resume_refuses_other_settings_and_a_torn_state_in_one_line(tmp_path, script):
    options = script.DEFAULTS | dict(quick=True)
    spec = paper_tune.Tuning(options)
    study = StudyRun.of(spec, tmp_path)
    study.prepare(spec.run_settings(), extra=spec.run_extra())  # what a run leaves
    for i in (0, 1):
        arrays, meta = tune.state_arrays(_fake_state())
        study.save(*spec.trial_record(i)[:1], settings=spec.trial_record(i)[1], arrays=arrays, meta=meta)
    proc = _run_tune_script("--resume", str(tmp_path), "--parameterisation", "full")
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1, proc.stderr
    assert proc.stderr.startswith(f"tune_mhat: error: --resume {tmp_path}: that run has tuner.parameterisation=")
    # without --resume, the same options name the run the folder holds and how to go on with it
    proc = _run_tune_script("--quick", "--parameterisation", "full", "--out", str(tmp_path))
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1, proc.stderr
    assert f"{tmp_path} holds a tuning run with tuner.parameterisation=diagonal (you asked full)" in proc.stderr
    assert f"(--resume {tmp_path})" in proc.stderr


@pytest.mark.slow  # about 30 s cold: a tuning run, interrupted and resumed
def test_a_tuning_run_resumes_from_its_last_record_to_the_same_numbers(tmp_path, script):
    """An interrupted run (its first iterations recorded) goes on from the last record, and a
    torn record is named and its iteration run again: the same gain as one run through."""
    options = script.DEFAULTS | dict(quick=True, iterations=2, compare=[0.25])
    whole = paper_tune.tune_mhat(paper_tune.Tuning(options), tmp_path / "whole")
    part = paper_tune.Tuning(options)
    first = engine.run(part, tmp_path / "part", batch_size=1, stop_after_batches=2)
    assert first.computed == ["iteration-0000", "iteration-0001"]
    torn = StudyRun.of(part, tmp_path / "part").record_path("iteration-0001")
    torn.write_bytes(torn.read_bytes()[:100])
    warnings = []
    second = engine.run(part, tmp_path / "part", batch_size=1, warn=warnings.append)
    assert second.computed == ["iteration-0001", "iteration-0002"] and len(warnings) == 1 and str(torn) in warnings[0]
    last = part.state(StudyRun.of(part, tmp_path / "part"), 2)
    np.testing.assert_array_equal(np.asarray(tune.mhat_from_theta(last.theta, "diagonal")), whole.finished[0])
