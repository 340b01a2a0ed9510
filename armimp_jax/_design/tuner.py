"""Gradient-based tuning of a controller gain (IMBIC's ``Mhat``): parameterisation, loss,
gradients, and an optimiser loop with a divergence guard. The paper's experiment (its
training and held-out batches) is ``armimp_jax.paper.mhat_experiment``.

``phi_T`` is differentiated through the whole pipeline (RK4 scan -> Welch -> ``Z`` ->
``phi_T``) with respect to ``Mhat``. ``Mhat`` is parameterised so it is always symmetric
positive definite: ``"diagonal"`` uses ``log`` of the two diagonal entries, ``"full"`` a
Cholesky factor with log-diagonal (3 numbers). The loss is the mean ``phi_T`` over a
training batch (plus, optionally, a weight times the mean ``phi_ij``).

Two gradient modes: ``"forward"`` (``jax.jacfwd``: one tangent per parameter, memory of
a few primal runs) and ``"reverse"`` (``jax.grad`` through the scan with ``jax.checkpoint``;
``Numerics.checkpoint`` says whether the tape holds one carry per control period
or per RK4 substep). Both are exact; ``bench_gradient.py`` measures them. Training
batches are best run with ``Numerics(solver=RK4(kernel="grad"), substeps=..., checkpoint="substep")`` (the
RK4 kernel arranged for reverse mode, a carry per substep on the tape: ``sweeps/bench_gradient.py``)
and are sharded over the devices (``place_batch``: one per core after ``runtime.configure``).

``tune`` runs optax with a divergence guard: a step that lands on an ``Mhat`` whose
simulation diverges (flag, NaN or inf) is rejected, the step size is halved, and the
rejection is logged; an unstable *start* is shrunk towards small ``Mhat`` (which
time-delay estimation tolerates) until it is stable. Its pieces are the optimiser's
``make_trainer`` (what a run holds fixed), ``start_state`` and ``step_state`` (one step, the
guard included): ``tune`` drives them in memory, the study engine one iteration per record
(``paper.mhat_experiment``).

The run's state is a ``TuneState`` (a NamedTuple pytree: ``theta``, Adam's state, the
gradient, counters, and a ``History`` of arrays). Pure JAX, no files: saving and resuming
it is ``armimp_jax.study.design.tuning``.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from .._batch import _batch_size, assess, make_mesh, shard_batch, to_host
from .._checks import check_choice
from .._estimation.welch import Welch
from .._pytree import replace_unchecked
from .._simulate import Trial, simulate
from .._solver.numerics import Numerics
from .._solver.rk4 import RK4
from .descent import descend, optimizer_or_default
from .spd import STRUCTURES, spd_from_theta, theta_from_spd

PARAMETERISATIONS = STRUCTURES
MAX_START_SHRINKS = 8  # an unstable start is halved at most this often (a factor of 256)


def mhat_from_theta(theta, parameterisation: str):
    """``Mhat`` [kg] ``(2, 2)``, symmetric positive definite, from the unconstrained ``theta``."""
    return spd_from_theta(theta, parameterisation)


def theta_from_mhat(mhat, parameterisation: str):
    """Inverse of ``mhat_from_theta`` (``mhat`` must be SPD; diagonal keeps only the diagonal)."""
    return theta_from_spd(mhat, parameterisation, name="Mhat")


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
    """Options of ``tune``: the ``Mhat`` parameterisation, Adam's learning rate (in units of
    ``theta``), the iteration budget, the gradient mode, the ``phi_ij`` weight of the loss,
    the step scale below which the descent stops, and the training numerics (default: the
    paper's RK4, 100 substeps, with the ``grad`` kernel and a carry per substep on the tape)."""

    parameterisation: str = "diagonal"
    learning_rate: float = 0.1
    iterations: int = 30
    mode: str = "reverse"
    phi_ij_weight: float = 0.0
    min_step_scale: float = 1e-3
    # the paper's RK4 at its 100 substeps, whatever Numerics() is (saved tuning states record it)
    numerics: Numerics = Numerics(solver=RK4(kernel="grad"), substeps=100, checkpoint="substep")


def config_settings(config: TuneConfig, optimizer=None) -> dict:
    """The options of ``config`` that steer the descent, as saved with a tuning state:
    everything but ``iterations`` (a run may be resumed with a larger budget). The optimiser is
    ``"adam"`` (the default) or ``"custom"`` (an optax transformation of the caller's, whose
    settings a record cannot hold: a state saved with one resumes only with ``optimizer=``)."""
    out = {f.name: getattr(config, f.name) for f in dataclasses.fields(config) if f.name != "iterations"}
    out["numerics"] = config.numerics.settings()
    return dict(out, optimiser="adam" if optimizer is None else "custom")


def n_parameters(parameterisation: str) -> int:
    """Length of ``theta``: 2 (``"diagonal"``) or 3 (``"full"``)."""
    check_choice("parameterisation", parameterisation, PARAMETERISATIONS)
    return 2 if parameterisation == "diagonal" else 3


class History(NamedTuple):
    """Every evaluated point of a tuning run, one row each (the start, then each proposal).

    ``iteration`` ``(k,)``; ``accepted`` ``(k,)`` (False: a rejected proposal); the training
    ``loss`` [N/m] and ``grad_norm`` ``(k,)`` (NaN where rejected); ``mhat`` ``(k, 2, 2)``
    [kg] (the proposal where rejected); ``step_scale`` and ``time_s`` [s] ``(k,)``; per
    training trial ``phi_T`` ``(k, B)`` [N/m] (NaN where rejected); held-out ``eval_phi_T``
    [N/m] (NaN where not evaluated) and ``eval_diverged`` ``(k,)``.
    """

    iteration: np.ndarray
    accepted: np.ndarray
    loss: np.ndarray
    grad_norm: np.ndarray
    mhat: np.ndarray
    step_scale: np.ndarray
    time_s: np.ndarray
    phi_T: np.ndarray
    eval_phi_T: np.ndarray
    eval_diverged: np.ndarray

    @classmethod
    def empty(cls, n_trials: int) -> History:
        f = np.empty(0)
        return cls(
            iteration=np.empty(0, int),
            accepted=np.empty(0, bool),
            loss=f,
            grad_norm=f,
            mhat=np.empty((0, 2, 2)),
            step_scale=f,
            time_s=f,
            phi_T=np.empty((0, n_trials)),
            eval_phi_T=f,
            eval_diverged=np.empty(0, bool),
        )

    def append(self, **row) -> History:
        """A history one row longer; fields not given are NaN (False for flags)."""
        unknown = row.keys() - set(self._fields)
        if unknown:
            raise ValueError(f"History has no field(s) {sorted(unknown)}")
        new = {}
        for name in self._fields:
            old = getattr(self, name)
            default = False if old.dtype == bool else np.nan
            value = np.broadcast_to(np.asarray(row.get(name, default), dtype=old.dtype), old.shape[1:])
            new[name] = np.concatenate([old, value[None]])
        return History(**new)

    def record(self, i: int) -> dict:
        """Row ``i`` as the JSON-able dict that ``tune`` logs (``plots.loss_curve`` reads these)."""
        i = range(len(self.iteration))[i]  # a negative index counts from the end
        it, mhat = int(self.iteration[i]), self.mhat[i].tolist()
        if not self.accepted[i]:
            return dict(
                iteration=it,
                event="rejected: diverged or non-finite",
                mhat=mhat,
                step_scale=float(self.step_scale[i]),
                time_s=float(self.time_s[i]),
            )
        rec = dict(
            iteration=it,
            event="start" if i == 0 else "step",
            loss=float(self.loss[i]),
            grad_norm=float(self.grad_norm[i]),
            mhat=mhat,
            phi_T=self.phi_T[i].tolist(),
            step_scale=float(self.step_scale[i]),
            time_s=float(self.time_s[i]),
        )
        if np.isfinite(self.eval_phi_T[i]) or self.eval_diverged[i]:
            rec["eval"] = dict(mean_phi_T=float(self.eval_phi_T[i]), diverged=bool(self.eval_diverged[i]))
        return rec

    def records(self) -> list[dict]:
        return [self.record(i) for i in range(len(self.iteration))]


class TuneState(NamedTuple):
    """Everything a tuning run needs to go on (a pytree): the parameters ``theta`` and the
    loss gradient there, Adam's state, the training loss [N/m] at ``theta``, the iteration
    count, the step scale of the divergence guard, the rejected-step count, and the history."""

    theta: jax.Array
    opt_state: optax.OptState
    grad: jax.Array
    value: float
    iteration: int
    step_scale: float
    rejected: int
    history: History


def place_batch(params: Trial, f_delta, *, mesh: Mesh | None = None):
    """Shard a stacked training batch's trial axis over the devices of ``mesh`` so that
    ``value_and_grad_fn`` runs on every core: jit partitions the vmapped loss, and the mean
    and the gradient are summed across devices (the last bits may differ from one device).

    Args:
        params: stacked trials, leading axis ``B`` (``stack_trials``).
        f_delta: perturbations ``(B, N, 2)`` [N].
        mesh: a one-axis mesh named ``"batch"`` (``armimp_jax._batch.make_mesh``); default every device.

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
    state: TuneState | None = None,
    log: Callable[[dict], None] = print,
    on_iteration: Callable[[TuneState], None] | None = None,
    evaluate: Callable[[int, jnp.ndarray], dict] | None = None,
    eval_every: int = 0,
    mesh: Mesh | None = None,
    optimizer=None,
) -> TuneState:
    """Descend the training loss from ``theta0`` with ``optimizer`` (an optax
    ``GradientTransformation``; default Adam at ``config.learning_rate``) and a divergence guard.

    ``state`` (from ``load_state``, or a previous call's ``on_iteration``) resumes a run;
    ``on_iteration`` receives the state after the start and after every iteration (accepted
    or rejected), e.g. to save it. ``evaluate(iteration, theta)`` returning
    ``{"mean_phi_T", "diverged"}`` runs every ``eval_every`` accepted iterations. The
    training batch is sharded over ``mesh`` (default: every device) by ``place_batch``, and
    the first log record says over how many devices. Returns the final ``TuneState``.
    """
    n_theta = n_parameters(config.parameterisation)
    if state is not None and np.shape(state.theta) != (n_theta,):
        raise ValueError(
            f"tune: the state has {np.shape(state.theta)[0]} parameters; parameterisation "
            f"{config.parameterisation!r} has {n_theta}"
        )
    opt = optimizer_or_default(optimizer, config.learning_rate, where="tune")
    trainer = make_trainer(params, f_delta, welch, config, mesh, log)
    if state is None:
        state = start_state(trainer, opt, theta0, log)
        log(state.history.record(-1))
        if on_iteration is not None:
            on_iteration(state)

    def after(state, _):
        log(state.history.record(-1))
        if on_iteration is not None:
            on_iteration(state)

    def stop(state):
        if state.step_scale < config.min_step_scale:
            log(dict(event="stopping: step scale below minimum"))
            return True
        return False

    def step(state, _):
        return step_state(trainer, opt, state, evaluate, eval_every)

    return descend(state, step, config.iterations, after=after, stop=stop, first=state.iteration)


class Trainer(NamedTuple):
    """What a tuning run holds fixed: the jitted loss value and gradient ``vg``, the placed
    training batch, the sharding ``theta`` is replicated with (None: unsharded), the batch
    size and the configuration."""

    vg: Callable
    params: Trial
    f_delta: jax.Array
    replicated: NamedSharding | None
    n_trials: int
    config: TuneConfig


def make_trainer(params, f_delta, welch, config: TuneConfig, mesh, log) -> Trainer:
    params, f_delta, placed = place_batch(params, f_delta, mesh=mesh)
    n_trials = int(params.q0.shape[0])
    log(dict(event="training batch", trials=n_trials, devices=1 if placed is None else placed.size))
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
    return Trainer(vg, params, f_delta, replicated, n_trials, config)


def _evaluate(trainer: Trainer, theta):
    """``(sound, loss, grad, aux, seconds)`` of the training batch at ``theta``; sound: finite
    and no trial diverged."""
    t0 = time.perf_counter()
    if trainer.replicated is not None:
        theta = jax.device_put(theta, trainer.replicated)
    (value, aux), grad = trainer.vg(theta, trainer.params, trainer.f_delta)
    aux = to_host(aux)  # per trial, so sharded like the batch (across hosts too)
    ok = _finite(value, grad) and not bool(np.any(np.asarray(aux.diverged)))
    return ok, float(value), grad, aux, time.perf_counter() - t0


def _mhat(trainer: Trainer, theta) -> np.ndarray:
    return np.asarray(mhat_from_theta(theta, trainer.config.parameterisation))


def _accepted_row(trainer: Trainer, iteration, theta, value, grad, aux, scale, dt, ev=None) -> dict:
    """The ``History`` row of an accepted point (``ev``: its held-out evaluation, if run)."""
    return dict(
        iteration=iteration,
        accepted=True,
        loss=value,
        grad_norm=float(jnp.linalg.norm(grad)),
        mhat=_mhat(trainer, theta),
        step_scale=scale,
        time_s=dt,
        phi_T=np.asarray(aux.phi_T),
        **({} if ev is None else dict(eval_phi_T=ev["mean_phi_T"], eval_diverged=ev["diverged"])),
    )


def start_state(trainer: Trainer, opt, theta0, log) -> TuneState:
    """The run's first state at ``theta0``, shrunk towards small ``Mhat`` (stable for TDE)
    while its training trials diverge."""
    theta = jnp.asarray(theta0, dtype=jnp.float64)
    ok, value, grad, aux, dt = _evaluate(trainer, theta)
    shrinks = 0
    while not ok:
        shrinks += 1
        if shrinks > MAX_START_SHRINKS:
            raise RuntimeError(
                f"no stable starting Mhat after halving it {MAX_START_SHRINKS} times (down to "
                f"{_mhat(trainer, theta).tolist()} kg): the training trials diverge for another reason, e.g. too "
                "few RK4 substeps for the LuGre bristles"
            )
        log(dict(event="start diverged", mhat=_mhat(trainer, theta).tolist()))
        theta = _shrink(theta, trainer.config.parameterisation)
        ok, value, grad, aux, dt = _evaluate(trainer, theta)
    history = History.empty(trainer.n_trials).append(**_accepted_row(trainer, 0, theta, value, grad, aux, 1.0, dt))
    return TuneState(theta, opt.init(theta), grad, value, 0, 1.0, 0, history)


def step_state(trainer: Trainer, opt, state: TuneState, evaluate, eval_every: int) -> TuneState:
    """One Adam step, scaled by the guard's step scale: accepted (the scale grows by 1.5, to
    at most 1) or, if the training trials diverge or give non-finite values, rejected (the
    scale halves)."""
    updates, new_opt = opt.update(state.grad, state.opt_state, state.theta)
    proposal = state.theta + state.step_scale * updates
    ok, value, grad, aux, dt = _evaluate(trainer, proposal)
    iteration = state.iteration + 1
    if not ok:
        scale = state.step_scale * 0.5
        history = state.history.append(
            iteration=iteration, accepted=False, mhat=_mhat(trainer, proposal), step_scale=scale, time_s=dt
        )
        return state._replace(iteration=iteration, step_scale=scale, rejected=state.rejected + 1, history=history)
    scale = min(1.0, state.step_scale * 1.5)
    run_eval = evaluate is not None and eval_every and iteration % eval_every == 0
    ev = evaluate(iteration, proposal) if run_eval else None
    history = state.history.append(**_accepted_row(trainer, iteration, proposal, value, grad, aux, scale, dt, ev))
    return TuneState(proposal, new_opt, grad, value, iteration, scale, state.rejected, history)


def _shrink(theta, parameterisation):
    """``theta`` of ``Mhat / 2``."""
    if parameterisation == "diagonal":
        return theta - math.log(2.0)
    half = 0.5 * math.log(2.0)  # L -> L / sqrt(2)
    return jnp.array([theta[0] - half, theta[1] / math.sqrt(2.0), theta[2] - half])
