"""Experiment design by gradient: the perturbation that gives the tightest estimates within a
patient's limits (``design``), and the record length a target needs (``record_for``).

A design moves a perturbation family's ``shape`` (its spectrum, ``_model/families.py``) to
minimise a criterion of ``identify``'s predicted standard errors (``predict.py``'s method:
the statistics' covariance over simulated noise draws through the friction-aware closed
loop), for one trial or over a set of trials (the patient's arm is what is unknown):

- ``criterion="max_relative_se"`` (default): the largest ``SE / |value|`` among the
  ``targets`` entries (e.g. the diagonals of M, B and K), over the trials (worst case) or
  averaged over them; smoothed for the gradient by a log-sum-exp of temperature
  ``SOFTMAX_TEMPERATURE`` (reported unsmoothed);
- ``criterion="d_optimal"``: the log-determinant of the targets' covariance in relative
  units (the volume of the confidence region).

**Limits are honoured by construction, not penalised**: the family's RMS is set to
``rms_force``, samples beyond ``peak_force`` are clipped and the rest re-scaled until both
hold (so a design uses the whole RMS it is allowed), then the whole signal is scaled down
until the hand's peak displacement in the noise-free simulation of every trial is at most
``peak_displacement``. So every signal the optimiser sees, and the one it
returns, meets them (the displacement's gain is re-found every ``REGAIN_EVERY`` steps and
for the returned design). Each step draws new noise (a stochastic gradient, optax's Adam):
a design that fitted one fixed set of draws would promise more than the experiment gives.
The last iterate is returned (a cosine-decayed rate with the second half's iterates
averaged was measured worse: docs/experiment_design.md). A step whose draws diverged or
gave a non-finite criterion is skipped and counted. The binding's Jacobian ``A`` is held at its value for the starting
design during the optimisation (it is near the identity and moves little with the
spectrum); the predictions before and after are computed afresh with ``predict_se`` on
the same draws, and if the design does not beat the start there, the start is returned
with ``improved=False``: a design never promises less than its start.
"""

from __future__ import annotations

import dataclasses
import math
import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from .._checks import require_x64
from .._model.families import Multisine, PaperNoise, ShapedNoise
from .._model.sensors import IDEAL
from .._pytree import replace_unchecked
from .._simulate import Trial, simulate
from . import indirect
from . import layout as lay
from .indirect import IDENTIFY_NUMERICS
from .predict import predict_se

CRITERIA = ("max_relative_se", "d_optimal")
AGGREGATES = ("worst", "mean")
SOFTMAX_TEMPERATURE = 0.05  # in log relative SE: the smooth maximum is within ~0.05 * log(n) of the true one
DISPLACEMENT_TOLERANCE = 1e-3  # of the gain, in the displacement limit's bisection
CLIP_ITERATIONS = 40  # clip-and-rescale passes of the peak limit: a few for Gaussian noise, ~30 for short bursts
REGAIN_EVERY = 10  # steps between re-finding the displacement gain (each is a bisection of forward runs)


@dataclasses.dataclass(frozen=True)
class Limits:
    """What a clinician allows: ``rms_force`` and ``peak_force`` [N] per axis of the
    perturbation ``F_Delta`` (scalars or ``(2,)``), ``peak_displacement`` [m] of the hand
    from its rest position in the noise-free simulation (``None``: no limit), and the record
    length ``record`` [s]."""

    rms_force: float | tuple
    peak_force: float | tuple
    record: float
    peak_displacement: float | None = None

    def __post_init__(self):
        rms = np.broadcast_to(np.asarray(self.rms_force, dtype=float), (2,))
        peak = np.broadcast_to(np.asarray(self.peak_force, dtype=float), (2,))
        if not np.all(rms > 0) or not np.all(np.isfinite(peak)):
            raise ValueError(
                f"Limits: rms_force must be > 0 N and peak_force finite, got {rms.tolist()}, {peak.tolist()}"
            )
        if np.any(peak < rms):
            raise ValueError(
                f"Limits: no signal meets peak_force {peak.tolist()} N below rms_force {rms.tolist()} N "
                "(a peak is at least the RMS)"
            )
        if not (math.isfinite(self.record) and self.record >= 2.0):
            raise ValueError(f"Limits: record must be >= 2 s, got {self.record}")
        if self.peak_displacement is not None and not self.peak_displacement > 0:
            raise ValueError(f"Limits: peak_displacement must be > 0 m or None, got {self.peak_displacement}")

    def n_samples(self, period: float) -> int:
        return int(round(self.record / period))


class Design(NamedTuple):
    """``design``'s answer (host values): the designed ``family`` (at its limited level) and its
    ``signal`` ``(N, 2)`` [N]; ``start_family`` and ``start_signal`` likewise; ``before`` and
    ``after``: per trial the ``PredictedSE`` of the start and of the design; ``criterion``
    before and after (unsmoothed); ``trace``: the smoothed criterion per optimisation step
    (on that step's draws; NaN for a skipped step); ``achieved``: RMS and peak force per
    axis [N] and the largest peak hand displacement over the trials [m] of the designed
    signal; ``improved``: whether the design beat the start (if not, ``family`` and
    ``signal`` are the start's); ``skipped``: steps skipped for diverged draws; ``time_s``;
    ``start_criteria``: the criterion of each candidate start (the family argument's order)."""

    family: object
    signal: np.ndarray
    start_family: object
    start_signal: np.ndarray
    before: list
    after: list
    criterion_before: float
    criterion_after: float
    trace: list
    achieved: dict
    improved: bool
    skipped: int
    time_s: float
    start_criteria: list


def _quiet(trial: Trial) -> Trial:
    return replace_unchecked(trial, sensors=IDEAL, voluntary=None)


@jax.jit
def _peak_displacement(trial, f):
    sim = simulate(_quiet(trial), f, numerics=IDENTIFY_NUMERICS)
    return jnp.max(jnp.linalg.norm(sim.x - trial.x0[None, :], axis=1)), sim.diverged


def _limited_signal(family, key, n, limits: Limits, period: float, gain=1.0):
    """The family's signal at ``rms_force`` with its peaks clipped to ``peak_force`` (the rest
    re-scaled so that the RMS stays at its limit), times ``gain``."""
    rms = jnp.broadcast_to(jnp.asarray(limits.rms_force, dtype=jnp.float64), (2,))
    peak = jnp.broadcast_to(jnp.asarray(limits.peak_force, dtype=jnp.float64), (2,))
    s = replace_unchecked(family, rms=rms).signal(key, n, period)
    peak = peak[None, :]

    def clip_and_rescale(_, s):
        c = jnp.clip(s, -peak, peak)
        return c * (rms / jnp.sqrt(jnp.mean(c * c, axis=0)))[None, :]

    # the fixed point has the RMS at its limit and the peak within it; a last clip makes the
    # peak exact whatever is left of the iteration (then the RMS is a hair below its limit)
    s = jnp.clip(jax.lax.fori_loop(0, CLIP_ITERATIONS, clip_and_rescale, s), -peak, peak)
    return s * gain


def limited_signal(family, limits: Limits, *, key, period: float = 1e-3, trials=None) -> np.ndarray:
    """The ``(N, 2)`` force [N] a family gives within ``limits``, as ``design`` makes it: at
    ``rms_force``, peaks clipped to ``peak_force`` (the rest re-scaled to keep the RMS), and,
    with ``trials`` and a ``peak_displacement``, scaled down until the hand's peak
    displacement in every trial's noise-free simulation is within it. ``N`` from
    ``limits.record`` and ``period`` [s]; ``key`` draws the family's noise (``design``'s
    start uses ``jax.random.split(key)[0]`` of its own key)."""
    require_x64("limited_signal")
    n = limits.n_samples(period)
    gain = 1.0 if trials is None else _displacement_gain(family, key, n, limits, list(trials), period)
    return np.asarray(_limited_signal(family, key, n, limits, period, gain))


def _displacement_gain(family, key, n, limits, trials, period):
    """The largest gain <= 1 (to ``DISPLACEMENT_TOLERANCE``) at which every trial's peak hand
    displacement is within the limit, by bisection: with friction the motion is far from
    proportional to the force (the joints stick below their breakaway torque)."""
    if limits.peak_displacement is None:
        return 1.0

    def within(gain):
        f = _limited_signal(family, key, n, limits, period, gain)
        peaks = [_peak_displacement(t, f) for t in trials]
        return not any(bool(d) for _, d in peaks) and max(float(p) for p, _ in peaks) <= limits.peak_displacement

    if within(1.0):
        return 1.0
    low, high = 0.0, 1.0
    while high - low > DISPLACEMENT_TOLERANCE:
        mid = 0.5 * (low + high)
        low, high = (mid, high) if within(mid) else (low, mid)
    if low == 0.0:
        raise ValueError(
            f"design: the hand's displacement stays above peak_displacement {limits.peak_displacement} m even at "
            f"{DISPLACEMENT_TOLERANCE:g} of the force limits; raise it or lower the force limits"
        )
    return low


def default_targets(layout) -> list[int]:
    """Indices of the default targets: every entry but the off-diagonals of a matrix, whose
    values may be near zero, so their relative SE is not a measure of precision."""
    return [i for i, lab in enumerate(layout.labels()) if not lab.endswith(("[0,1]", "[1,0]"))]


def relative_se(pred, trial: Trial, *, free, targets) -> dict:
    """``{label: SE / |value|}`` of the ``targets`` entries from ``pred`` (a ``PredictedSE`` of
    ``trial`` for the parameters ``free``), the values being ``trial``'s own."""
    layout = lay.make_layout(free)
    labels = layout.labels()
    values = np.asarray(lay.natural(layout, lay.pack(layout, trial), trial))
    se = np.sqrt(np.diag(np.asarray(pred.covariance)))
    return {t: float(se[labels.index(t)] / abs(values[labels.index(t)])) for t in targets}


def _targets(layout, targets):
    """Indices into the natural vector of the ``targets`` labels (default: ``default_targets``)."""
    labels = layout.labels()
    if targets is None:
        return default_targets(layout)
    if isinstance(targets, str):
        targets = [targets]
    if not len(targets):
        raise ValueError("design: targets must name at least one entry (or be None)")
    bad = [t for t in targets if t not in labels]
    if bad:
        raise ValueError(f"design: unknown target {bad[0]!r}; the free parameters' entries are {', '.join(labels)}")
    return [labels.index(t) for t in targets]


def _criterion_value(cov, values, idx, criterion):
    """The criterion of one trial from its natural covariance and values: the log relative SEs
    ``(k,)`` (max_relative_se) or the log-determinant in relative units (d_optimal)."""
    idx = np.asarray(idx)
    sub = cov[idx][:, idx] / jnp.outer(jnp.abs(values[idx]), jnp.abs(values[idx]))
    if criterion == "d_optimal":  # per entry, in log SE like max_relative_se (half the log variance)
        return 0.5 * jnp.linalg.slogdet(sub)[1][None] / len(idx)
    return 0.5 * jnp.log(jnp.diag(sub))


def _aggregate(per_trial, criterion, aggregate, smooth: bool):
    """One number from the per-trial log criteria ``(T, k)``: a (smooth) maximum over the
    targets, then the worst or the mean over the trials; returned as a plain ratio (exp)."""
    per_trial = jnp.stack(per_trial)
    t = SOFTMAX_TEMPERATURE
    if criterion == "max_relative_se":
        inner = t * jax.nn.logsumexp(per_trial / t, axis=1) if smooth else jnp.max(per_trial, axis=1)
    else:
        inner = per_trial[:, 0]
    if aggregate == "worst":
        outer = t * jax.nn.logsumexp(inner / t) if smooth else jnp.max(inner)
    else:
        outer = jnp.mean(inner)
    return jnp.exp(outer)


def _designable(family):
    if isinstance(family, PaperNoise):
        raise ValueError("design: PaperNoise has no shape to design; start from a ShapedNoise or a Multisine")
    if not isinstance(family, (ShapedNoise, Multisine)):
        raise ValueError(f"design: family must be a ShapedNoise or a Multisine, got {type(family).__name__}")


def design(
    trial: Trial,
    family,
    *,
    free,
    limits: Limits,
    targets=None,
    criterion: str = "max_relative_se",
    robust_over=None,
    aggregate: str = "worst",
    steps: int = 40,
    learning_rate: float = 0.15,
    draws: int = 16,
    predict_draws: int = 64,
    key=None,
    progress=None,
) -> Design:
    """Design the perturbation: the ``family``'s spectrum that minimises ``criterion`` within ``limits``.

    Args:
        trial: the planned experiment (robot, controller, friction, sensors' and voluntary
            force's noise, and an arm: the truth assumed).
        family: the starting perturbation (``ShapedNoise`` or ``Multisine``); its ``shape``
            is designed, its level set by ``limits``. Or a list of candidate starts (e.g.
            ``ShapedNoise``s of several burst ``duty``s, which no gradient moves): each is
            predicted on the same draws and the design starts from the best
            (``Design.start_criteria``).
        free: the parameters ``identify`` will estimate (names as ``identify``).
        limits: ``Limits`` (RMS and peak force, peak displacement, record length).
        targets: labels of the entries the criterion weighs (e.g. ``"arm.stiffness[0,0]"``);
            default every free entry but the off-diagonals of the matrices.
        criterion: ``"max_relative_se"`` or ``"d_optimal"``.
        robust_over: trials to design for at once (e.g. one per arm the patient may have);
            default ``[trial]``. Each must share ``trial``'s controller type and acquisition.
        aggregate: ``"worst"`` (min-max) or ``"mean"`` over ``robust_over``.
        steps, learning_rate: Adam steps on the log of ``shape``.
        draws: noise draws per trial per step (new ones every step).
        predict_draws: draws of the final ``predict_se`` before and after.
        key: ``jax.random`` key (default ``key(0)``): the family's own noise and every draw.
        progress: ``None`` or a callable ``progress(step, steps, value)`` called after each step.

    Returns a ``Design``. One-line ``ValueError`` before any long computation for an unknown
    parameter or target, a family with frequencies at or above the control rate's Nyquist
    frequency (checked by the family), or limits no signal can meet.
    """
    require_x64("design")
    t_start = time.perf_counter()
    if not isinstance(trial, Trial):
        raise ValueError(f"design: trial must be a Trial (from make_trial), got {type(trial).__name__}")
    candidates = list(family) if isinstance(family, (list, tuple)) else [family]
    if not candidates:
        raise ValueError("design: family must be a family or a non-empty list of candidate families")
    for c in candidates:
        _designable(c)
    if criterion not in CRITERIA:
        raise ValueError(f"design: unknown criterion {criterion!r}; allowed: {', '.join(CRITERIA)}")
    if aggregate not in AGGREGATES:
        raise ValueError(f"design: unknown aggregate {aggregate!r}; allowed: {', '.join(AGGREGATES)}")
    if not isinstance(limits, Limits):
        raise ValueError(f"design: limits must be a Limits, got {type(limits).__name__}")
    layout = lay.make_layout(free)
    idx = _targets(layout, targets)
    trials = [trial] if robust_over is None else list(robust_over)
    if not trials or not all(isinstance(t, Trial) for t in trials):
        raise ValueError("design: robust_over must be a non-empty list of Trials")
    for i, t in enumerate(trials):
        if t.sensors.ideal and t.voluntary is None:
            raise ValueError(
                f"design: trial {i} has no noise (ideal sensors, no voluntary force): every design is exact"
            )
        same = (
            type(t.controller) is type(trial.controller),
            t.acquisition == trial.acquisition,
            t.period == trial.period,
        )
        if not all(same):
            raise ValueError(
                f"design: robust_over[{i}] must share the trial's controller type, acquisition and period; got "
                f"{type(t.controller).__name__}/{t.acquisition}/{t.period} s against "
                f"{type(trial.controller).__name__}/{trial.acquisition}/{trial.period} s"
            )
    for name, v, low in (("steps", steps, 1), ("draws", draws, 8), ("predict_draws", predict_draws, 8)):
        if not (isinstance(v, (int, np.integer)) and v >= low):
            raise ValueError(f"design: {name} must be an integer >= {low}, got {v!r}")
    if not (isinstance(learning_rate, (int, float)) and 0 < learning_rate < 10):
        raise ValueError(f"design: learning_rate must lie in (0, 10) (a step in log amplitude), got {learning_rate!r}")
    key = jax.random.key(0) if key is None else key
    family_key, draw_key = jax.random.split(key)
    period = trial.period
    n = limits.n_samples(period)
    n_draws, n_jac = indirect.draw_counts(trial, draws, 2)

    points = [lay.pack(layout, t) for t in trials]
    values = [lay.natural(layout, p, t) for t, p in zip(trials, points)]
    predict_key = jax.random.fold_in(draw_key, 2 * 10**6)

    def predictions(f):
        preds = [
            predict_se(t, f, free=free, statistic="welch", key=predict_key, draws=predict_draws, jacobian_draws=8)
            for t in trials
        ]
        bad = [i for i, pr in enumerate(preds) if bool(pr.diverged)]
        if bad:
            raise RuntimeError(f"design: the prediction's simulations diverged for trial {bad[0]} of robust_over")
        return preds

    def plain(preds):
        per_trial = [_criterion_value(pr.covariance, v, idx, criterion) for pr, v in zip(preds, values)]
        return float(_aggregate(per_trial, criterion, aggregate, smooth=False))

    # the start: the candidate the prediction rates best (on the same draws)
    starts = []
    for c in candidates:
        g = _displacement_gain(c, family_key, n, limits, trials, period)
        f = _limited_signal(c, family_key, n, limits, period, g)
        preds = predictions(f) if len(candidates) > 1 else None
        starts.append((c, g, f, preds, plain(preds) if preds is not None else None))
    family, gain, f0, before, _ = min(starts, key=lambda st: st[4] if st[4] is not None else 0.0)
    start_criteria = [st[4] for st in starts]

    # the binding's Jacobian of each trial, held during the optimisation (near the identity)
    jac_keys = jax.random.split(jax.random.fold_in(draw_key, 10**6), n_jac)
    # one at a time (block): programs split over the CPU devices must not queue up together
    jacs = [
        jax.block_until_ready(indirect.binding_jacobian(layout, t, p, f0, jac_keys, IDENTIFY_NUMERICS)[0])
        for t, p in zip(trials, points)
    ]
    naturals = [lay.natural_jacobian(layout, p, t) for t, p in zip(trials, points)]

    def objective(log_shape, keys, gain, smooth=True):
        fam = replace_unchecked(family, shape=jnp.exp(log_shape))
        f = _limited_signal(fam, family_key, n, limits, period, gain)
        per_trial, diverged = [], jnp.bool_(False)
        for t, p, jac, g, v in zip(trials, points, jacs, naturals, values):
            stats, div = indirect.binding_draws(layout, t, p, f, keys, IDENTIFY_NUMERICS)
            diverged = diverged | jnp.any(div)
            cov = g @ indirect.covariance(jac, stats, n_draws) @ g.T
            per_trial.append(_criterion_value(cov, v, idx, criterion))
        return _aggregate(per_trial, criterion, aggregate, smooth), diverged

    value_and_grad = jax.jit(jax.value_and_grad(objective, has_aux=True))
    shape0 = np.asarray(family.shape)
    log_shape = np.log(np.maximum(shape0, 1e-6 * shape0.max()))
    opt = optax.adam(learning_rate)
    state = opt.init(log_shape)
    trace, skipped = [], 0
    for step in range(steps):
        keys = jax.random.split(jax.random.fold_in(draw_key, step), n_draws)
        (value, diverged), grad = value_and_grad(log_shape, keys, gain)
        grad = np.asarray(grad)
        if bool(diverged) or not (np.isfinite(float(value)) and np.all(np.isfinite(grad))):
            skipped += 1  # a diverged draw poisons the criterion: no step on it
            trace.append(float("nan"))
        else:
            trace.append(float(value))
            updates, state = opt.update(grad, state)
            # kept on the host: arrays placed by the sharded step would make the next call recompile
            log_shape = np.asarray(log_shape + updates)
            state = jax.tree.map(np.asarray, state)
        # the displacement limit is re-checked as the spectrum moves (it scales the whole signal)
        if limits.peak_displacement is not None and (step + 1) % REGAIN_EVERY == 0:
            gain = _displacement_gain(
                replace_unchecked(family, shape=jnp.exp(log_shape)), family_key, n, limits, trials, period
            )
        if progress is not None:
            progress(step + 1, steps, trace[-1])
    if skipped == steps:
        raise RuntimeError(f"design: every step's noise draws diverged ({steps} steps); the trial is unstable")

    designed = replace_unchecked(family, shape=np.exp(log_shape))
    gain_after = _displacement_gain(designed, family_key, n, limits, trials, period)
    signal = np.asarray(_limited_signal(designed, family_key, n, limits, period, gain_after))
    start_signal = np.asarray(f0)
    before = predictions(jnp.asarray(start_signal)) if before is None else before
    after = predictions(jnp.asarray(signal))
    if start_criteria[0] is None:
        start_criteria = [plain(before)]
    improved = plain(after) < plain(before)
    if not improved:  # same draws for both: the start is the better design
        designed, signal, after = family, start_signal, before
    displacement = max(float(_peak_displacement(t, jnp.asarray(signal))[0]) for t in trials)
    final_rms = np.sqrt(np.mean(signal**2, axis=0))
    achieved = dict(
        rms_force=final_rms.tolist(),
        peak_force=np.max(np.abs(signal), axis=0).tolist(),
        peak_displacement=displacement,
    )
    return Design(
        family=replace_unchecked(designed, rms=final_rms),
        signal=signal,
        start_family=replace_unchecked(family, rms=np.sqrt(np.mean(start_signal**2, axis=0))),
        start_signal=start_signal,
        before=before,
        after=after,
        criterion_before=plain(before),
        criterion_after=plain(after),
        trace=trace,
        achieved=achieved,
        improved=improved,
        skipped=skipped,
        start_criteria=start_criteria,
        time_s=time.perf_counter() - t_start,
    )


def record_for(
    trial: Trial,
    f,
    *,
    free,
    target: dict,
    draws: int = 64,
    key=None,
) -> dict:
    """The shortest record [s] at which ``identify``'s relative SE of each ``target`` entry
    reaches its goal, for the perturbation ``f`` ``(N, 2)`` (repeated or cut to length).

    ``target`` maps entry labels to relative SEs (``{"arm.stiffness[1,1]": 0.05}``: +-5% at
    one SE, about +-10% at 95%). From ``predict_se`` at the given length, SEs fall as one over
    the square root of the length (``tests/test_identify.py`` checks that law); the answer is
    then predicted again at that length (a second ``predict_se``, reported, not enforced: the
    law holds to the draws' noise). Returns ``{label: seconds}`` and ``"record_s"``, the
    longest of them, with the relative SEs predicted there (``"check"``)."""
    require_x64("record_for")
    layout = lay.make_layout(free)
    labels = layout.labels()
    if not isinstance(target, dict) or not target:
        raise ValueError(f"record_for: target must map entry labels to relative SEs, got {target!r}")
    bad = [t for t in target if t not in labels]
    if bad:
        raise ValueError(f"record_for: unknown target {bad[0]!r}; the free parameters' entries are {', '.join(labels)}")
    if not all(0 < float(v) < 1 for v in target.values()):
        raise ValueError(f"record_for: target relative SEs must lie in (0, 1), got {target}")
    f = np.asarray(f, dtype=float)
    period = trial.period

    def relative(pred):
        return relative_se(pred, trial, free=free, targets=target)

    now = relative(predict_se(trial, f, free=free, statistic="welch", draws=draws, key=key))
    seconds = f.shape[0] * period
    need = {t: seconds * (now[t] / float(target[t])) ** 2 for t in target}
    record_s = max(need.values())
    n = max(int(math.ceil(record_s / period)), 1000)
    longer = np.resize(f, (n, 2))  # repeats the perturbation (or cuts it)
    check = relative(predict_se(trial, longer, free=free, statistic="welch", draws=draws, key=key))
    return {**need, "record_s": n * period, "check": check}
