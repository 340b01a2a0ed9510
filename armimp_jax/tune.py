"""Gradient-based tuning of a controller gain (IMBIC's ``Mhat``): parameterisation, loss,
gradients, and an optimiser loop with a divergence guard. The paper's experiment (its
training and held-out batches) is ``armimp_jax.paper.tune``.

``phi_T`` is differentiated through the whole pipeline (RK4 scan -> Welch -> ``Z`` ->
``phi_T``) with respect to ``Mhat``. ``Mhat`` is parameterised so it is always symmetric
positive definite: ``"diagonal"`` uses ``log`` of the two diagonal entries, ``"full"`` a
Cholesky factor with log-diagonal (3 numbers). The loss is the mean ``phi_T`` over a
training batch (plus, optionally, a weight times the mean ``phi_ij``).

Two gradient modes: ``"forward"`` (``jax.jacfwd``: one tangent per parameter, memory of
a few primal runs) and ``"reverse"`` (``jax.grad`` through the scan with ``jax.checkpoint``;
``Numerics.checkpoint`` says whether the tape holds one carry per control period
or per RK4 substep). Both are exact; ``bench_gradient.py`` measures them. Training
batches are best run with ``Numerics(kernel="grad", checkpoint="substep")`` (the RK4 kernel
arranged for reverse mode, a carry per substep on the tape: ``sweeps/bench_gradient.py``)
and are sharded over the devices (``place_batch``: one per core after ``runtime.configure``).

``tune`` runs optax with a divergence guard: a step that lands on an ``Mhat`` whose
simulation diverges (flag, NaN or inf) is rejected, the step size is halved, and the
rejection is logged; an unstable *start* is shrunk towards small ``Mhat`` (which
time-delay estimation tolerates) until it is stable.
"""

from __future__ import annotations

import dataclasses
import json
import math
import pathlib
import time
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from ._batch import Welch, _batch_size, assess, make_mesh, shard_batch, to_host
from ._checks import check_choice
from ._numerics import Numerics
from ._pytree import replace_unchecked
from ._simulate import Trial, simulate

PARAMETERISATIONS = ("diagonal", "full")
MAX_START_SHRINKS = 8  # an unstable start is halved at most this often (a factor of 256)


def mhat_from_theta(theta, parameterisation: str):
    """``Mhat`` [kg] ``(2, 2)``, symmetric positive definite, from the unconstrained ``theta``."""
    if parameterisation == "diagonal":
        return jnp.diag(jnp.exp(theta))
    lower = jnp.array([[jnp.exp(theta[0]), 0.0], [theta[1], jnp.exp(theta[2])]])
    return lower @ lower.T


def theta_from_mhat(mhat, parameterisation: str):
    """Inverse of ``mhat_from_theta`` (``mhat`` must be SPD; diagonal keeps only the diagonal)."""
    mhat = np.asarray(mhat, dtype=float)
    if parameterisation == "diagonal":
        if np.any(np.diag(mhat) <= 0):
            raise ValueError(f"Mhat diagonal must be positive, got {np.diag(mhat).tolist()}")
        return jnp.log(jnp.asarray(np.diag(mhat)))
    try:
        lower = np.linalg.cholesky(mhat)
    except np.linalg.LinAlgError:
        raise ValueError(f"Mhat must be symmetric positive definite, got {mhat.tolist()}") from None
    return jnp.array([np.log(lower[0, 0]), lower[1, 0], np.log(lower[1, 1])])


def with_mhat(trials: Trial, mhat) -> Trial:
    """``trials`` (single or stacked IMBIC trials) with the gain replaced by ``mhat`` ``(2, 2)``."""
    ctrl = trials.controller
    if not hasattr(ctrl, "mhat"):
        raise ValueError(f"with_mhat: the trials' controller {type(ctrl).__name__} has no mhat")
    batch_shape = jnp.shape(ctrl.mhat)[:-2]
    new = replace_unchecked(ctrl, mhat=jnp.broadcast_to(mhat, batch_shape + (2, 2)))
    return replace_unchecked(trials, controller=new)


class LossAux(NamedTuple):
    """Per-trial diagnostics of a loss evaluation: ``phi_T`` ``(B,)`` and divergence flags ``(B,)``."""

    phi_T: jnp.ndarray
    diverged: jnp.ndarray


def trial_loss(trial: Trial, f_delta, welch: Welch, phi_ij_weight: float = 0.0, numerics: Numerics | None = None):
    """``phi_T`` (+ weight x mean ``phi_ij``) of one trial, and its divergence flag."""
    out = assess(trial, f_delta, simulate(trial, f_delta, numerics=numerics), welch)
    return out.phi_T + phi_ij_weight * jnp.mean(out.phi_ij), (out.phi_T, out.diverged)


def batch_loss(
    theta,
    trials: Trial,
    f_delta,
    *,
    parameterisation: str,
    welch: Welch,
    phi_ij_weight: float = 0.0,
    numerics: Numerics | None = None,
):
    """Mean loss over a stacked batch as a pure function of ``theta``; returns ``(loss, LossAux)``."""
    p = with_mhat(trials, mhat_from_theta(theta, parameterisation))
    losses, (phi_t, diverged) = jax.vmap(lambda t, f: trial_loss(t, f, welch, phi_ij_weight, numerics))(p, f_delta)
    return jnp.mean(losses), LossAux(phi_t, diverged)


def value_and_grad_fn(
    *,
    parameterisation: str,
    welch: Welch,
    phi_ij_weight: float = 0.0,
    mode: str = "forward",
    numerics: Numerics | None = None,
):
    """A jitted ``(theta, trials, f_delta) -> ((loss, aux), grad)`` in the chosen mode."""
    check_choice("gradient mode", mode, ("forward", "reverse"))
    check_choice("parameterisation", parameterisation, PARAMETERISATIONS)

    def loss(theta, params, f_delta):
        return batch_loss(
            theta,
            params,
            f_delta,
            parameterisation=parameterisation,
            welch=welch,
            phi_ij_weight=phi_ij_weight,
            numerics=numerics,
        )

    if mode == "reverse":
        return jax.jit(jax.value_and_grad(loss, has_aux=True))

    def fwd(theta, params, f_delta):
        # One tangent per parameter, vmapped: the primal does not depend on the tangent,
        # so vmap computes it once; memory stays that of a few primal runs.
        def tangent(v):
            return jax.jvp(lambda t: loss(t, params, f_delta), (theta,), (v,), has_aux=True)

        values, grads, aux = jax.vmap(tangent)(jnp.eye(theta.shape[0]))
        return (values[0], jax.tree.map(lambda a: a[0], aux)), grads

    return jax.jit(fwd)


@dataclasses.dataclass
class TuneConfig:
    parameterisation: str = "diagonal"
    learning_rate: float = 0.1
    iterations: int = 30
    mode: str = "reverse"
    phi_ij_weight: float = 0.0
    min_step_scale: float = 1e-3
    numerics: Numerics = Numerics(kernel="grad", checkpoint="substep")


def place_batch(params: Trial, f_delta, *, mesh: Mesh | None = None):
    """Shard a stacked training batch's trial axis over the devices of ``mesh`` so that
    ``value_and_grad_fn`` runs on every core: jit partitions the vmapped loss, and the mean
    and the gradient are summed across devices (the last bits may differ from one device).

    Args:
        params: stacked trials, leading axis ``B`` (``stack_trials``).
        f_delta: perturbations ``(B, N, 2)`` [N].
        mesh: a one-axis mesh named ``"batch"`` (``sweep.make_mesh``); default every device.

    The batch is never padded: repeated trials would re-weight the mean loss. It spans the
    largest number of the mesh's devices that divides ``B`` (16 trials on 6 devices: 4;
    a prime ``B`` larger than the mesh: one device, where it is left as it is). Returns
    ``(params, f_delta, mesh)``, the last the mesh the batch spans (``None`` if unsharded).
    """
    mesh = make_mesh() if mesh is None else mesh
    n_trials = _batch_size((params, f_delta))
    n_devices = max(d for d in range(1, mesh.size + 1) if n_trials % d == 0)
    if n_devices == 1:
        return params, f_delta, None
    mesh = Mesh(mesh.devices.flat[:n_devices], mesh.axis_names)
    (params, f_delta), _ = shard_batch((params, f_delta), mesh, lanes=1)
    return params, f_delta, mesh


def _finite(*trees) -> bool:
    return all(bool(np.all(np.isfinite(np.asarray(x)))) for x in jax.tree.leaves(trees))


def tune(
    theta0,
    params: Trial,
    f_delta,
    welch: Welch,
    config: TuneConfig,
    *,
    state: dict | None = None,
    log: Callable[[dict], None] = print,
    on_iteration: Callable[[dict], None] | None = None,
    evaluate: Callable[[int, jnp.ndarray], dict] | None = None,
    eval_every: int = 0,
    mesh: Mesh | None = None,
) -> dict:
    """Descend the training loss from ``theta0`` with optax Adam and a divergence guard.

    ``state`` (from a previous call's ``on_iteration``) resumes a run. The training batch
    is sharded over ``mesh`` (default: every device) by ``place_batch``, and the first log
    record says over how many devices. Returns the final state: ``theta``, ``mhat``,
    ``history`` (one record per iteration), optimiser state.
    """
    params, f_delta, placed = place_batch(params, f_delta, mesh=mesh)
    log(dict(event="training batch", trials=int(params.q0.shape[0]), devices=1 if placed is None else placed.size))
    # theta replicated like the gradients that come back, so every step reuses the first
    # compilation (a proposal built from them would otherwise differ in sharding: 23 s more)
    replicated = None if placed is None else NamedSharding(placed, PartitionSpec())
    vg = value_and_grad_fn(
        parameterisation=config.parameterisation,
        welch=welch,
        phi_ij_weight=config.phi_ij_weight,
        mode=config.mode,
        numerics=config.numerics,
    )
    opt = optax.adam(config.learning_rate)

    def evaluate_at(theta):
        t0 = time.perf_counter()
        if replicated is not None:
            theta = jax.device_put(theta, replicated)
        (value, aux), grad = vg(theta, params, f_delta)
        aux = to_host(aux)  # per trial, so sharded like the batch (across hosts too)
        ok = _finite(value, grad) and not bool(np.any(np.asarray(aux.diverged)))
        return ok, float(value), grad, aux, time.perf_counter() - t0

    if state is None:
        theta = jnp.asarray(theta0, dtype=jnp.float64)
        ok, value, grad, aux, dt = evaluate_at(theta)
        shrinks = 0
        while not ok:  # an unstable start: shrink Mhat (small gains are stable for TDE)
            shrinks += 1
            if shrinks > MAX_START_SHRINKS:
                raise RuntimeError(
                    f"no stable starting Mhat after halving it {MAX_START_SHRINKS} times (now "
                    f"{np.asarray(mhat_from_theta(theta, config.parameterisation)).tolist()} kg): the training "
                    "trials diverge for another reason, e.g. too few RK4 substeps for the LuGre bristles"
                )
            log(dict(event="start diverged", mhat=np.asarray(mhat_from_theta(theta, config.parameterisation)).tolist()))
            theta = _shrink(theta, config.parameterisation)
            ok, value, grad, aux, dt = evaluate_at(theta)
        state = dict(
            iteration=0,
            theta=theta,
            opt_state=opt.init(theta),
            step_scale=1.0,
            history=[],
            value=value,
            grad=grad,
            rejected=0,
        )
        _record(state, config, value, grad, aux, dt, event="start")
        log(state["history"][-1])
    while state["iteration"] < config.iterations:
        theta, grad = state["theta"], state["grad"]
        updates, new_opt = opt.update(grad, state["opt_state"], theta)
        proposal = theta + state["step_scale"] * updates
        ok, value, new_grad, aux, dt = evaluate_at(proposal)
        state["iteration"] += 1
        if not ok:
            state["step_scale"] *= 0.5
            state["rejected"] += 1
            rec = dict(
                iteration=state["iteration"],
                event="rejected: diverged or non-finite",
                mhat=np.asarray(mhat_from_theta(proposal, config.parameterisation)).tolist(),
                step_scale=state["step_scale"],
                time_s=dt,
            )
            state["history"].append(rec)
            log(rec)
            if state["step_scale"] < config.min_step_scale:
                log(dict(event="stopping: step scale below minimum"))
                break
            continue
        state.update(
            theta=proposal,
            opt_state=new_opt,
            value=value,
            grad=new_grad,
            step_scale=min(1.0, state["step_scale"] * 1.5),
        )
        _record(state, config, value, new_grad, aux, dt, event="step")
        if evaluate is not None and eval_every and state["iteration"] % eval_every == 0:
            state["history"][-1]["eval"] = evaluate(state["iteration"], proposal)
        log(state["history"][-1])
        if on_iteration is not None:
            on_iteration(state)
    return state


def _shrink(theta, parameterisation):
    """``theta`` of ``Mhat / 2``."""
    if parameterisation == "diagonal":
        return theta - math.log(2.0)
    half = 0.5 * math.log(2.0)  # L -> L / sqrt(2)
    return jnp.array([theta[0] - half, theta[1] / math.sqrt(2.0), theta[2] - half])


def _record(state, config, value, grad, aux, dt, *, event):
    state["history"].append(
        dict(
            iteration=state["iteration"],
            event=event,
            loss=value,
            grad_norm=float(jnp.linalg.norm(grad)),
            mhat=np.asarray(mhat_from_theta(state["theta"], config.parameterisation)).tolist(),
            phi_T=np.asarray(aux.phi_T).tolist(),
            step_scale=state["step_scale"],
            time_s=dt,
        )
    )


def save_state(path: pathlib.Path, state: dict, config: TuneConfig) -> None:
    """Everything needed to resume: theta, optimiser state leaves, history (JSON + NPZ)."""
    leaves = jax.tree.leaves(state["opt_state"])
    np.savez(
        path.with_suffix(".npz"),
        theta=np.asarray(state["theta"]),
        grad=np.asarray(state["grad"]),
        **{f"opt_{i}": np.asarray(x) for i, x in enumerate(leaves)},
    )
    meta = {k: state[k] for k in ("iteration", "step_scale", "history", "value", "rejected")}
    path.with_suffix(".json").write_text(json.dumps(dict(config=dataclasses.asdict(config), **meta), indent=1))


def load_state(path: pathlib.Path, config: TuneConfig) -> dict:
    meta = json.loads(path.with_suffix(".json").read_text())
    with np.load(path.with_suffix(".npz")) as data:
        theta = jnp.asarray(data["theta"])
        template = optax.adam(config.learning_rate).init(theta)
        leaves = [jnp.asarray(data[f"opt_{i}"]) for i in range(len(jax.tree.leaves(template)))]
        opt_state = jax.tree.unflatten(jax.tree.structure(template), leaves)
        grad = jnp.asarray(data["grad"])
    return dict(
        theta=theta,
        opt_state=opt_state,
        grad=grad,
        **{k: meta[k] for k in ("iteration", "step_scale", "history", "value", "rejected")},
    )
