"""Identify an arm (and the robot's friction) through the closed-loop model: ``identify``.

Given the commanded ``F_Delta`` and the recorded hand position and force, estimate named
parameters of a trial by **indirect inference** (``indirect.py``): find the parameters at
which recordings simulated through the friction-aware closed loop, with the trial's own
noise, give on average the same statistics as the lab's recording.

The statistics (``auxiliary.py``): for the arm, by default the **efficient statistic**
(``efficient.py``), one generalised least-squares step of the frictionless loop linearised
about rest, with the loop's coloured noise whitened by its Kalman filter, centred where the
recording itself puts the arm (``efficient.fit_linear``). Near a linear loop its variance is
the Cramér-Rao bound (``bound.py``), and the simulation corrects what the linear model leaves
out (friction, sampling, the robot's kinematics). ``statistic="welch"`` is the classical
Welch fit instead (1 Hz bins: blind at the low frequencies where stiffness shows). For the
friction, a regression of the joint torques.

Several recordings (``Recording``: postures, trials, the robot alone) are identified in one
call (``pool.py``): shared parameters (the robot's friction, inertia, force channel) once,
the arm once per group (posture), with one joint covariance.

Why match statistics and not fit the signals: with the person's own force and the sensors'
noise fed back through a loop with friction, the noise-free simulation is not the mean of
the noisy loop, and an output-error fit's 95% intervals covered the truth 42-74% of the time
(docs/identification.md). Statistics matched in expectation carry all of that into the
simulation: the estimate is consistent, and its covariance comes from the spread of the
statistics over noise draws, the loop's feedback and coloured noise included.

The search (``search.py``): Gauss-Newton on the mismatch of statistics, the binding's
Jacobian reused between steps, friction parameters held by a wide prior about their start
(nuisances for the arm: one the recording cannot tell, such as the Coulomb torque under
IMBIC, which cancels it, is flagged in ``not_told`` and its uncertainty carried into the
arm's intervals). Then the result's assembly: the covariance at the estimate (through
friction checked against re-estimates from recordings simulated there, and widened entry by
entry where the fit is not linear across the intervals: ``search.spread_ratio``), warnings in
a lab's terms (``diagnosis.py``: joints that stood still), fit quality and the classical answer.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import sys
import time
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from .._checks import as_float64, check_int, require_x64
from .._estimation.ensemble import Ensemble
from .._estimation.welch import check_finite
from .._simulate import Trial
from .._solver.numerics import Numerics
from . import calibration_prior, efficient, indirect, linear, search
from . import layout as lay
from . import pool as pl
from .auxiliary import check_statistic_record, statistic_labels, statistics
from .bound import has_friction, is_near_linear
from .calibration_prior import ESTIMABLE
from .ensemble_identify import identify_over
from .pool import Recording
from .predict import check_sampling
from .result import Identification, assemble, classical_fit, predict_jit

MIN_SAMPLES = 1024  # the Welch statistic's least at 1 kHz (4 segments of 256 samples: 3 bins to 15 Hz)
CHANNELS = ("x1", "x2", "fh1", "fh2")


def check_recording(f, x, fh, where: str):
    """``(f, x, fh)`` as float64 ``(N, 2)`` arrays: one-line errors for a wrong shape, NaN or inf
    (naming the array and sample), mismatched lengths or fewer than ``MIN_SAMPLES`` samples."""
    arrays = {}
    for name, a in (("f", f), ("x", x), ("fh", fh)):
        arr = as_float64(name, a, where=where)
        if arr.ndim != 2 or arr.shape[1] != 2:
            raise ValueError(f"{where}: {name} must have shape (N, 2), got {arr.shape}")
        check_finite(name, arr, where=where)
        arrays[name] = arr
    lengths = {k: v.shape[0] for k, v in arrays.items()}
    if len(set(lengths.values())) > 1:
        raise ValueError(f"{where}: f, x and fh must have the same length, got {lengths}")
    if lengths["f"] < MIN_SAMPLES:
        raise ValueError(f"{where}: the record must hold at least {MIN_SAMPLES} samples, got {lengths['f']}")
    return arrays["f"], arrays["x"], arrays["fh"]


@functools.partial(jax.jit, static_argnames="layout")
def _statistics(layout, model, f, x, fh, arm_stat):
    return statistics(layout, model, f, x, fh, arm_stat)


def _recordings(model, f, x, fh) -> list[Recording]:
    """The recordings of the call (one ``Trial`` with its arrays, or a list of ``Recording``),
    their arrays checked (one-line errors naming the recording)."""
    if isinstance(model, Trial):
        return [Recording(model, *check_recording(f, x, fh, "identify"))]
    items = list(model) if isinstance(model, (list, tuple)) else None
    if not items or not all(isinstance(r, Recording) for r in items):
        raise ValueError(
            f"identify: model must be a Trial (from make_trial) or a list of Recording, got {type(model).__name__}"
        )
    if not (f is None and x is None and fh is None):
        raise ValueError("identify: with a list of Recording, give f, x and fh in each Recording, not beside it")
    out = []
    for i, r in enumerate(items):
        if not isinstance(r.model, Trial):
            raise ValueError(f"identify: recording {i + 1}'s model must be a Trial, got {type(r.model).__name__}")
        out.append(r._replace(f=None, x=None, fh=None)._replace(**_arrays(r, f"identify: recording {i + 1}")))
    if len({type(r.model.friction) for r in out}) > 1:
        raise ValueError("identify: every recording's robot must have the same kind of friction law (one robot)")
    if len({r.model.noisy for r in out}) > 1:
        raise ValueError("identify: every recording's model must have noise (Sensors, VoluntaryForce), or none")
    return out


def _calibrated(recordings, calibration, free):
    """``(recordings, calibration_prior.Calibrated | None)``. A ``RobotCalibration``
    (``calibrate_robot``), a ``ForceCalibration`` (``calibrate_force``) or a list of them: every
    model takes their values and holds them, and their covariance is carried into the free
    parameters' (``calibration_prior.py``); refused in one line if it is of another robot (link
    lengths, base) than a model's, or covers a parameter named in ``free``."""
    if calibration is None:
        return recordings, None
    return calibration_prior.apply(recordings, calibration, free)


def _arrays(r: Recording, where: str) -> dict:
    f, x, fh = check_recording(r.f, r.x, r.fh, where)
    return dict(f=f, x=x, fh=fh)


def _check(recordings, free, symmetric, shared, statistic, numerics, draws, jacobian_draws, max_steps):
    """Every one-line refusal before long work; the checked values."""
    friction = recordings[0].model.friction
    layout = lay.make_layout(free, symmetric, friction=friction)
    for i, r in enumerate(recordings):
        where = "identify" if len(recordings) == 1 else f"identify: recording {i + 1}"
        check_statistic_record(r.f.shape[0], r.model.period, where)
        for name, arr in (("x", r.x), ("fh", r.fh)):
            flat = [f"{name}[:, {j}]" for j in range(2) if not float(jnp.std(arr[:, j])) > 0]
            if flat and not (name == "fh" and pl.robot_alone(r.model)):
                raise ValueError(f"{where}: the recorded channel(s) {flat} are constant; nothing to fit")
        if any(n.startswith("sensors.") for n in layout.names) and r.model.acquisition != "instant":
            raise ValueError(f"{where}: the force channel's calibration needs acquisition 'instant'")
    numerics, draws, jacobian_draws = check_sampling("identify", statistic, numerics, draws, jacobian_draws)
    calibration = [n for n in layout.names if n in lay.LINEAR and n not in lay.ARM_PARAMETERS]
    if calibration and statistic == "welch":
        raise ValueError(f"identify: {', '.join(calibration)} need the efficient statistic; use statistic='auto'")
    shared = tuple(n for n in layout.names if n not in lay.ARM_PARAMETERS) if shared is None else tuple(shared)
    unknown = [n for n in shared if n not in layout.names]
    if unknown:
        raise ValueError(f"identify: shared names {unknown}, which are not free; free: {list(layout.names)}")
    max_steps = check_int("max_steps", max_steps, minimum=1)
    return layout, shared, numerics, draws, jacobian_draws, max_steps


def _arm_statistic(layout, model, p, f, x, fh, statistic, numerics, keys):
    """The statistic of the linearised loop's parameters (the arm's, the robot's, the force
    channel's; ``None``: Welch), its centre (``None`` for Welch) and its name.

    ``auto`` takes the efficient statistic unless the model's loop is far from linear
    (``bound.is_near_linear``: stick-slip), where the Welch fit is the safer for the arm (the
    calibration's parameters always take the efficient one). The efficient statistic is
    centred where the recording puts the parameters (``_centre``). Under friction the
    innovations are weighed by their spread in recordings simulated at that centre
    (``efficient.excess_weight``)."""
    arm = indirect.arm_layout(layout)
    calibration = arm is not None and any(n not in lay.ARM_PARAMETERS for n in arm.names)
    if (
        arm is None
        or statistic == "welch"
        or (statistic == "auto" and not calibration and not is_near_linear(model, f, numerics))
    ):
        return None, None, "welch"
    # a free force offset (a constant on the recorded force) beside the arm leaves the centre the
    # arm's own, the classical fit's, which Welch's segment means make blind to it: the
    # frictionless linear fit holds the offset at its start, and a start 1 SE of the robot alone's
    # off (0.25 mN) widened the arm's SEs 2-3 times (docs/identification.md section 4d)
    others = [n for n in arm.names if n not in lay.ARM_PARAMETERS]
    if others and len(others) < len(arm.names) and all(n in ESTIMABLE for n in others):
        calibration = False
    centred, weight = _centre(layout, model, p, f, x, fh, keys, numerics, arm, calibration)
    stat = indirect.arm_statistic(layout, model, jnp.asarray(centred), f, weight)
    return jax.block_until_ready(stat), centred, "efficient"


def _centre(layout, model, p, f, x, fh, keys, numerics, arm, calibration):
    """``(centre, weight)``: where the efficient statistic is linearised, and its weight.

    Through friction the centre is the recording's classical fit (``classical_centre``): the
    frictionless linear fit of a recording with friction lies in a long flat valley, and a
    statistic centred where this one recording happens to put it gave estimates 5 SE off that
    the recordings simulated at the estimate did not show (docs/identification.md, section 6c).
    Elsewhere (or where the classical fit is unusable) it is the frictionless linear fit
    (``efficient.fit_linear``) from the model's start. The weight comes from recordings
    simulated at the centre, before the fit uses it."""
    classical = classical_centre(layout, model, p, f, x, fh) if has_friction(model) and not calibration else None
    centred = p.copy() if classical is None else classical
    weight = _weight(layout, model, centred, f, keys, numerics)
    if classical is not None and weight is None:  # the classical fit's loop diverges when simulated
        centred, weight = p.copy(), _weight(layout, model, p, f, keys, numerics)
    if has_friction(model) and model.noisy and weight is None:
        raise ValueError("identify: noisy simulations of the model diverge at the start; choose another start")
    if classical is not None and centred is classical:
        return centred, weight
    # The centre moves the arm alone, or the calibration where the robot is alone: a frictionless
    # linear fit of both to one recording with friction was seen to run far off.
    names = lay.ARM_PARAMETERS if not pl.robot_alone(model) else tuple(n for n in arm.names)
    own = layout.index(names)
    if own.size:
        at = lay.with_values(layout, model, jnp.asarray(p))
        only = lay.Layout(*zip(*[(n, s) for n, s in zip(arm.names, arm.symmetric, strict=True) if n in names]))
        ref, converged = efficient.fit_linear(only, at, p[own], f, efficient.recorded(model, x, fh), weight)
        if converged or not calibration:  # a fit that did not settle beside a calibration: keep the start
            centred[own] = ref
    return centred, weight


def _weight(layout, model, p, f, keys, numerics):
    """The efficient statistic's weight under friction, from noisy recordings simulated at ``p``
    (``None`` without friction or noise, and where they diverge)."""
    if not (has_friction(model) and model.noisy):
        return None
    # friction's effect is no part of the linear loop: weigh the innovations by their spread
    # in recordings simulated with it before the fit uses them
    weight_keys = keys[: indirect.weight_draws(keys.shape[0])]
    weight = indirect.statistic_weight(layout, model, jnp.asarray(p), f, weight_keys, numerics)
    # one program in flight at a time: two that split over the CPU devices and meet at
    # collectives, queued together, can each hold a thread the other waits for
    weight = jax.block_until_ready(weight)
    return weight if np.all(np.isfinite(np.asarray(weight))) else None


def classical_centre(layout, model, p, f, x, fh):
    """``p`` with the arm's matrices at the recording's classical fit (Welch and ``fit_impedance``
    with the trial's acquisition), or ``None`` where that fit is missing (a record too short),
    not finite, or leaves the linearised loop unstable."""
    fit = classical_fit(f, x, fh, model.acquisition, model.period)
    if fit is None:
        return None
    values = {n: np.asarray(getattr(fit, n.split(".")[1]), dtype=float) for n in lay.ARM_PARAMETERS}
    if not all(np.all(np.isfinite(v)) for v in values.values()):
        return None
    for name, sym in zip(layout.names, layout.symmetric, strict=True):
        if sym and name in values:
            values[name] = 0.5 * (values[name] + values[name].T)
    at = lay.with_values(layout, model, jnp.asarray(p))
    try:  # the arm's own checks (a mass that is not positive definite, say)
        arm = dataclasses.replace(at.arm, **{n.split(".")[1]: jnp.asarray(v) for n, v in values.items()})
    except ValueError:
        return None
    trial = dataclasses.replace(at, arm=arm)
    if not linear.spectral_radius(linear.loop_of(trial)) < 1.0:
        return None
    out = np.array(p, dtype=float)
    own = layout.index(lay.ARM_PARAMETERS)
    out[own] = np.asarray(lay.pack(layout, trial))[own]
    return out


def identify(
    model,
    f=None,
    x=None,
    fh=None,
    *,
    free,
    symmetric=(),
    shared=None,
    statistic: str = "auto",
    numerics: Numerics | None = None,
    key=None,
    draws: int = 64,
    jacobian_draws: int = 8,
    max_steps: int = 20,
    progress: Callable[[dict], None] | bool | None = None,
    calibration=None,
) -> Identification:
    """Estimate parameters from one recording, or several, through the closed-loop simulation.

    Args:
        model: a ``Trial`` holding every fixed setting (robot, controller, acquisition,
            sensors' and voluntary force's noise levels, which the intervals rest on) and the
            starting values of the free parameters; or a list of ``Recording`` (each its own
            ``Trial``, perturbation and recording, of any length; ``f``, ``x``, ``fh`` then
            ``None``): postures, repeated trials, the robot alone (``aj.presets.no_arm``).
        f: the commanded perturbation ``F_Delta`` ``(N, 2)`` [N]; or an ``Ensemble`` of reaches.
        x, fh: the recorded hand position [m] and force [N], ``(N, 2)`` each.
        free: names of the parameters to estimate, from ``"arm.mass"``, ``"arm.damping"``,
            ``"arm.stiffness"`` (full 2x2), the friction law's ``IDENTIFIABLE`` ones as
            ``"friction.<name>"`` (per joint: LuGre's ``tau_c``, ``tau_s``, ``sigma0``,
            ``sigma1``, ``sigma2``; CoulombViscous's ``tau_c``, ``viscous``), the robot's link
            inertias ``"robot.inertia"`` (``(c1, c2, c3)`` [kg m^2]) and the recorded force
            channel's ``"sensors.force_gain"``, ``"sensors.force_offset"`` [N] and
            ``"sensors.force_delay"`` [s] (``Sensors``).
        symmetric: free arm matrices to constrain symmetric (3 numbers instead of 4).
        shared: the free names one value serves for every recording; the others take one
            value per group of recordings (``Recording.group``). Default: every name but the
            arm's (one robot, its friction and force channel; an arm per posture).
        statistic: the statistic of the arm (and of the calibration's parameters):
            ``"efficient"`` (module docstring), ``"welch"``, or ``"auto"`` (default: efficient
            unless a loop is far from linear).
        numerics: integration settings (default ``IDENTIFY_NUMERICS``: converged at every friction in [0, 4] N m).
        key: ``jax.random`` key of the simulated noise draws (default ``key(0)``: deterministic);
            each recording, and an ensemble's simulated ensembles, draw on a stream of their own.
        draws: noise draws ``R`` behind the binding and the covariance (>= 8; rounded up to
            a multiple of the local devices). The SEs carry a Monte Carlo error of about
            ``1 / sqrt(2 R)``, the estimate's variance ``1 / R`` more; friction's check needs 11.
        jacobian_draws, max_steps: draws averaged in the Jacobian ``A`` (1 to ``draws``); Gauss-Newton steps at most.
        progress: a function called after each step with ``{"step", "cost", "step_se",
            "seconds"}``, or ``True`` for one line per step on stderr.
        calibration: a ``RobotCalibration``, ``ForceCalibration`` or list: held, and carried (``_calibrated``).

    Returns an ``Identification``. Raises a one-line ``ValueError`` before any long computation for an
    unknown parameter, NaN or inf in a recording, mismatched lengths, a calibration of another robot, or a
    start at which a model diverges. A fit that does not converge has ``converged=False``, ``message`` why."""
    require_x64("identify")
    if isinstance(f, Ensemble):  # the reaches of a movement, every knot free (ensemble_identify.py)
        return identify_over(model, f, x, fh, calibration, free=free, numerics=numerics, max_steps=max_steps, key=key)
    t_start = time.perf_counter()
    recordings, calibrated = _calibrated(_recordings(model, f, x, fh), calibration, free)
    checked = _check(recordings, free, symmetric, shared, statistic, numerics, draws, jacobian_draws, max_steps)
    layout, shared, numerics, draws, jacobian_draws, max_steps = checked
    pool = pl.make_pool(recordings, layout.names, tuple(n for n, s in zip(layout.names, layout.symmetric) if s), shared)
    p = pl.pack(pool)
    groups = pl.templates(recordings, pool.groups)
    parts, centred, names, forward_s = _parts(
        recordings, pool, groups, p, statistic, numerics, key, draws, jacobian_draws
    )
    start = centred if not _diverges(parts, centred, numerics) else p
    n_jac = indirect.draw_counts(recordings[0].model, draws, jacobian_draws)[1]
    problem = _problem(parts, groups, recordings, pool, p, numerics, n_jac)._replace(calibration=calibrated)
    state = _init(problem, start, p)
    report = _reporter(progress, t_start)
    while not state.done:
        state = search.step(problem, state, max_steps)
        report(state)
    part_of = {r: t for t, members in enumerate(groups) for r in members}
    recorded = [(part_of[i], r.x, r.fh) for i, r in enumerate(recordings)]
    return assemble(problem, state, pool, recorded, ", ".join(dict.fromkeys(names)), t_start, forward_s[0])


def _parts(recordings, pool: pl.Pool, groups, p, statistic, numerics, key, draws, jacobian_draws):
    """One search part per template (recordings sharing a model and a perturbation), its
    statistic, and the start centred on each group's arm; the forward seconds at the start."""
    key = jax.random.key(0) if key is None else key
    n_draws, _ = indirect.draw_counts(recordings[0].model, draws, jacobian_draws)
    parts, centred, names, forward_s = [], p.copy(), [], []
    for t, members in enumerate(groups):
        r = members[0]  # the template's first recording centres its statistic
        rec, rlayout, index = recordings[r], pool.layouts[r], pool.indices[r]
        keys = jax.random.split(key if t == 0 else jax.random.fold_in(key, t), n_draws)
        forward_s.append(_checked_start(rlayout, rec.model, p[index], rec.f, numerics))
        stat, at, name = _arm_statistic(rlayout, rec.model, p[index], rec.f, rec.x, rec.fh, statistic, numerics, keys)
        if at is not None:  # a group's first recording centres its arm, the first robot alone the calibration
            own = indirect.arm_index(rlayout) if len(recordings) == 1 else _own(rlayout, pool, r, recordings)
            unset = centred[index[own]] == p[index[own]]
            centred[index[own]] = np.where(unset, at[own], centred[index[own]])
        parts.append(search.Part(rlayout, rec.model, rec.f, keys, stat, index, len(members)))
        names.append(name)
    return parts, centred, names, forward_s


def _own(layout: lay.Layout, pool: pl.Pool, r: int, recordings) -> np.ndarray:
    """Positions in recording ``r``'s ``p`` of what its centre sets in a pooled start: its group's
    arm if it is the group's first; the calibration if the robot is alone."""
    if pl.robot_alone(recordings[r].model):
        return layout.index(tuple(n for n in layout.names if n in lay.LINEAR))
    if pool.groups.index(pool.groups[r]) != r:
        return np.zeros(0, dtype=int)
    return layout.index(lay.ARM_PARAMETERS)


def _diverges(parts, p, numerics) -> bool:
    """Whether a noise-free simulation of any recording diverges at ``p``."""
    return any(bool(predict_jit(pt.layout, pt.model, jnp.asarray(p[pt.index]), pt.f, numerics)[1]) for pt in parts)


def _reporter(progress, t_start):
    """``report(state)`` after each step: ``progress``'s function, a line on stderr, or nothing."""
    if not progress:
        return lambda state: None
    if progress is True:

        def progress(info):
            move = info["step_se"]  # no SE without noise: the move is then not in SEs
            moved = f"largest move {move:.3g} SE, " if math.isfinite(move) else ""
            sys.stderr.write(
                f"identify: step {info['step']}, mismatch {info['cost']:.4g}, {moved}{info['seconds']:.0f} s\n"
            )
            sys.stderr.flush()

    def report(state):
        if state.history:
            last = state.history[-1]
            info = dict(step=len(state.history), cost=last["cost"], step_se=last["step_se"])
            progress(info | dict(seconds=time.perf_counter() - t_start))

    return report


def _checked_start(layout, model, p, f, numerics) -> float:
    """The wall time [s] of one noise-free simulation at the start ``p``; a one-line error if
    the model diverges there."""
    _, diverged = predict_jit(layout, model, jnp.asarray(p), f, numerics)
    if bool(diverged):
        start = {n: np.asarray(v).tolist() for n, v in lay.split(layout, jnp.asarray(p), model).items()}
        raise ValueError(f"identify: the model diverges at the starting values {start}; choose another start")
    t0 = time.perf_counter()
    jax.block_until_ready(predict_jit(layout, model, jnp.asarray(p), f, numerics))
    return time.perf_counter() - t0


def _problem(parts, groups, recordings, pool: pl.Pool, p0, numerics, n_jac) -> search.Problem:
    """What the search holds fixed: the recordings' statistics (the mean over a template's
    recordings), the nuisance prior and the slack; a one-line error for statistics a recording
    leaves undefined."""
    bs = []
    for part, members in zip(parts, groups, strict=True):
        b = []
        for i in members:
            rec = recordings[i]
            b.append(np.asarray(_statistics(part.layout, part.model, rec.f, rec.x, rec.fh, part.arm_stat)))
            if not np.all(np.isfinite(b[-1])):
                bad = [lab for lab, v in zip(statistic_labels(part.layout), b[-1], strict=True) if not np.isfinite(v)]
                which = "" if len(recordings) == 1 else f" (recording {i + 1})"
                raise ValueError(
                    f"identify: the recording's statistics {', '.join(bad)}{which} are not finite (a joint that never "
                    "moves leaves its friction unmeasured); free fewer friction parameters or record with more motion"
                )
        bs.append(b[0] if len(b) == 1 else np.mean(b, axis=0))
    b = np.concatenate(bs)
    noisy = recordings[0].model.noisy
    # the nuisance prior: every parameter but the arm's, of a noisy model (without noise there is
    # no spread to weigh it by)
    arm = np.concatenate([blk.slice.start + blk.layout.index(lay.ARM_PARAMETERS) for blk in pool.blocks])
    prior_index = np.setdiff1d(np.arange(p0.size), arm) if noisy else np.zeros(0, dtype=int)
    prior_mean = p0[prior_index]
    n_draws = parts[0].keys.shape[0]
    slack = b.size / n_draws if noisy else 1e-24 * (1.0 + float(b @ b))  # the binding's own MC jitter
    statistics_and_prior = np.concatenate([b, prior_mean])
    # through friction the binding's tangent misses its chord over the SEs (search._slope)
    chord = noisy and any(has_friction(r.model) for r in recordings)
    return search.Problem(
        tuple(parts), numerics, n_jac, noisy, statistics_and_prior, prior_index, prior_mean, slack, p0.size, chord
    )


def _init(problem: search.Problem, start, given) -> search.Search:
    """The search's first state at ``start``; if the model's noisy simulations diverge there
    (the linear fit's start, which no noise-free run checked), at the user's ``given`` start."""
    try:
        return search.init(problem, start)
    except ValueError:
        if start is given:
            raise
        return search.init(problem, given)
