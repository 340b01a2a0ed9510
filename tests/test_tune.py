"""Gradients of phi_T w.r.t. Mhat (both modes vs finite differences) and the tuner's guard."""

import json
import os
import pathlib
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import armimp_jax as aj
from armimp_jax import Welch, tune
from armimp_jax import paper as presets
from armimp_jax._batch import make_mesh
from armimp_jax.paper import tune as paper_tune

WELCH = Welch(512, 384)
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


def test_gradient_matches_finite_differences_at_friction_0_and_2(short_batch):
    params, f_delta = short_batch
    theta = tune.theta_from_mhat(0.4 * np.eye(2), "diagonal")
    jac = jax.jit(jax.jacfwd(_per_trial_losses))(theta, params, f_delta)  # rows: friction 0, friction 2
    assert np.all(np.isfinite(jac)) and np.all(jac != 0)
    f = jax.jit(_per_trial_losses)
    eps = 1e-3
    fd = np.stack(
        [(f(theta + eps * e, params, f_delta) - f(theta - eps * e, params, f_delta)) / (2 * eps) for e in jnp.eye(2)],
        axis=1,
    )
    np.testing.assert_allclose(jac, fd, rtol=2e-5)


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


@pytest.mark.parametrize("kernel", ["fast", "grad"])
def test_no_nan_in_the_gradient_at_friction_0(kernel):
    params = aj.stack_trials([presets.trial("imbic", 0, loc) for loc in (1, 3)])
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


def test_short_tuning_run_lowers_the_loss_from_a_poor_start():
    params, f_delta = paper_tune.training_batch((2,), (1,), (0,), seconds=1.6)
    config = tune.TuneConfig(learning_rate=0.3, iterations=4, numerics=NUM)
    logs = []
    state = tune.tune(
        tune.theta_from_mhat(1.5 * np.eye(2), "diagonal"), params, f_delta, WELCH, config, log=logs.append
    )
    losses = [h["loss"] for h in state["history"] if "loss" in h]
    assert len(losses) >= 3 and losses[-1] < losses[0]
    assert np.all(np.diag(tune.mhat_from_theta(state["theta"], "diagonal")) < 1.5)


def test_divergence_guard_on_unstable_start_and_on_unstable_steps(tmp_path):
    params, f_delta = paper_tune.training_batch((1,), (1,), (0,), seconds=1.6)
    logs = []
    # an unstable start (far above 2 M_x): shrunk until stable, and said so
    config = tune.TuneConfig(learning_rate=0.1, iterations=1, numerics=NUM)
    state = tune.tune(
        tune.theta_from_mhat(40.0 * np.eye(2), "diagonal"), params, f_delta, WELCH, config, log=logs.append
    )
    assert any(r.get("event") == "start diverged" for r in logs)
    assert np.isfinite(state["value"])
    # steps that land on unstable gains (a deliberately huge ascent step) are rejected, not taken
    logs.clear()
    config = tune.TuneConfig(learning_rate=-6.0, iterations=2, numerics=NUM)
    state = tune.tune(
        tune.theta_from_mhat(0.3 * np.eye(2), "diagonal"),
        params,
        f_delta,
        WELCH,
        config,
        log=logs.append,
        on_iteration=lambda st: tune.save_state(tmp_path / "s", st, config),
    )
    rejected = [r for r in logs if str(r.get("event", "")).startswith("rejected")]
    assert rejected and state["rejected"] >= 1 and state["step_scale"] < 1.0
    assert np.all(np.isfinite(np.asarray(state["theta"]))) and np.isfinite(state["value"])
    # ...and the saved state resumes where it stopped
    tune.save_state(tmp_path / "s", state, config)
    again = tune.load_state(tmp_path / "s", config)
    np.testing.assert_array_equal(again["theta"], state["theta"])
    assert again["iteration"] == state["iteration"] and again["history"] == state["history"]


SHARDED_GRADIENT = """
import json, logging, re
from armimp_jax.runtime import configure
configure(host_devices=3)
import jax, numpy as np
from armimp_jax import Welch, tune
from armimp_jax.paper import tune as paper_tune
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
out["tune"] = dict(compiles=len(compiled), steps=state["iteration"], first=logs[0])
print(json.dumps(out))
"""

# Subprocesses that set their own device count: the parent's XLA flags and platform stay out.
CPU_ENV = dict(os.environ, XLA_FLAGS="", JAX_PLATFORMS="cpu")


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
    mhat = np.array(json.loads((tmp_path / "mhat.json").read_text())["mhat"])
    assert mhat.shape == (2, 2) and np.all(np.linalg.eigvalsh(mhat) > 0)
    for name in ("loss_curve.png", "comparison.md", "comparison.json", "tune_state.json", "tune_state.npz"):
        assert (tmp_path / name).stat().st_size > 0, name
    assert "| tuned |" in (tmp_path / "comparison.md").read_text()
    # two host devices (runtime.configure keeps a count that is set): 8 training trials span both
    assert '"event": "training batch", "trials": 8, "devices": 2' in proc.stdout
