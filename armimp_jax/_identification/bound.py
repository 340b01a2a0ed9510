"""The Cramér-Rao bound of a planned experiment: ``fisher_information`` and ``crlb``.

The precision any unbiased estimator can reach from one recording of a near-linear loop
(docs/model.md section 18). The recorded ``y = (x - x0, F_h)`` is the loop's deterministic
response to the known perturbation plus the response to its noise (the person's force, the
sensors' noise fed back through the controller, the encoders' steps), both from the loop
linearised about rest (``linear.py``). The noise's Kalman filter (``kalman.py``) whitens it
exactly, so the information of the arm's parameters ``theta`` is

    I(theta) = sum_t de_t^T Lambda^-1 de_t,     de = whiten(d y_det / d theta),

and the bound is ``sqrt(diag(I^-1))``. The noise model is held fixed (what the person does
is not something a lab knows, so the noise's own dependence on ``theta`` adds nothing): this
is the bound a free noise model allows. Joint friction is left out of the loop: for IMBIC
with friction it is the loop IMBIC promises to leave; where friction (or the amplitude) takes
the hand's motion far from that loop, ``crlb`` says so and gives no number (PD through
stick-slip: no such bound holds; ``predict_se`` remains the measure there).

``fisher_information`` is pure JAX: differentiable in the perturbation and in every float of
the trial (controller gains included), so experiment design can use it.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np

from .._checks import as_float64, require_x64
from .._estimation.welch import check_finite
from .._model.sensors import quiet
from .._pytree import replace_unchecked
from .._simulate import Trial, simulate
from . import calibration_prior, kalman, linear
from . import layout as lay
from .indirect import IDENTIFY_NUMERICS
from .precision import record_seconds

ARM = ("arm.mass", "arm.damping", "arm.stiffness")
# The hand's motion counts as near-linear when its RMS departure from the frictionless linear
# loop's is below this fraction of its RMS, on each axis (measured: IMBIC up to 4 N m of Coulomb
# friction 0.02-0.09 at the paper's level 1; PD 0.14-1.0 from 0.05 N m).
NEAR_LINEAR = 0.1
DIAGONALS = tuple(f"{n}[{i},{i}]" for n in ARM for i in range(2))


def check_bound_inputs(trial: Trial, f, free, symmetric, where: str):
    """The layout of ``free`` (arm matrices only) and ``f`` as float64 ``(N, 2)``; one-line errors."""
    if not isinstance(trial, Trial):
        raise ValueError(f"{where}: trial must be a Trial (from make_trial), got {type(trial).__name__}")
    layout = _bound_layout(free, symmetric, where)
    f = as_float64("f", f, where=where)
    if f.ndim != 2 or f.shape[1] != 2 or f.shape[0] < 8:
        raise ValueError(f"{where}: f must have shape (N, 2) with N >= 8 samples, got {f.shape}")
    check_finite("f", f, where=where)
    return layout, f


def _bound_layout(free, symmetric, where: str) -> lay.Layout:
    """The layout of the bound's free parameters (the arm's matrices); one line naming the
    function asked and the parameters it takes otherwise."""
    free = (free,) if isinstance(free, str) else tuple(free)
    other = [n for n in free if n not in lay.ARM_PARAMETERS]
    unknown = [n for n in other if n not in lay.parameter_units(None)]
    if unknown:
        raise ValueError(f"{where}: unknown parameter {unknown[0]!r}; the bound's: {', '.join(lay.ARM_PARAMETERS)}")
    if other:
        raise ValueError(
            f"{where}: the bound covers the arm's matrices ({', '.join(lay.ARM_PARAMETERS)}), not {other}: friction "
            "is outside the linearised loop"
        )
    return lay.make_layout(free, symmetric, where=where)


def response_derivative(layout: lay.Layout, trial: Trial, p, f):
    """``(y (N, 4), dy/dp (N, 4, n))``: the linearised loop's deterministic response to ``f``
    at the parameters ``p`` of ``layout`` (``x - x0`` [m], ``F_h`` [N]) and its derivative."""

    def response(q):
        return linear.respond(linear.linearise(lay.with_values(layout, trial, q)), f)

    return response(p), jax.jacfwd(response)(p)


def fisher_information(trial: Trial, f, *, free=ARM, symmetric=()):
    """Fisher information ``(n, n)`` of the free arm parameters (``layout.make_layout(free,
    symmetric)``'s internal order: the entries row by row, three for a symmetric matrix) from
    one recording of ``trial`` under the perturbation ``f`` ``(N, 2)`` [N]; see the module
    docstring. Units: per (kg, N s/m, N/m)^2.

    Pure JAX (one jitted program) and single-trial: ``jax.grad`` flows to ``f`` and to every
    float of ``trial``; ``jax.vmap`` batches trials. The loop must be stable (``crlb`` checks
    it)."""
    return _fisher(_bound_layout(free, symmetric, "fisher_information"), trial, f)


@functools.partial(jax.jit, static_argnames="layout")
def _fisher(layout, trial, f):
    _, dy = response_derivative(layout, trial, lay.pack_arm(layout, trial), f)
    return kalman.information(kalman.innovations_filter(linear.linearise(trial)), dy)


@dataclasses.dataclass(frozen=True)
class Bound:
    """``crlb``'s answer (host values).

    Attributes:
        se, values, relative_se: ``{name: (2, 2) array}``: the bound on each entry's standard
            error (in its units), the trial's values, and their ratio (NaN where a value is 0).
        covariance: ``(n, n)`` the bound on the covariance of every entry (order of ``labels``);
            information: ``(m, m)`` the Fisher information of the internal parameters. Both NaN
            where no bound holds (``near_linear`` False: not computed).
        labels: entry names, e.g. ``"arm.stiffness[0,0]"``.
        seconds: the record length [s] the bound is for.
        reference: what the bound is of: the trial's loop, or that loop without its joint
            friction (the loop IMBIC promises to leave).
        near_linear: whether a bound holds: every recorded channel carries reading noise
            (``silent_readings``) and the trial's own hand motion stays within ``NEAR_LINEAR`` of
            the reference loop's; when not, ``se`` is NaN and ``message`` says why.
        nonlinearity: ``(4,)`` RMS departure of the trial's noise-free ``x`` and ``F_h`` from
            the reference loop's, relative to their RMS (NaN when not checked).
        spectral_radius: of the linearised loop per control period (stable below 1).
        message: empty, or why no bound is given.
        calibration_share: ``(n, n)`` the calibration's share of ``covariance`` (``crlb(...,
            calibration=)``; zeros without one); calibration_outside: the calibrated labels
            outside the linearised loop (the Coulomb torque), whose share the bound leaves out.
    """

    se: dict
    values: dict
    relative_se: dict
    covariance: np.ndarray
    information: np.ndarray
    labels: list
    seconds: float
    reference: str
    near_linear: bool
    nonlinearity: np.ndarray
    spectral_radius: float
    message: str
    calibration_share: np.ndarray | None = None
    calibration_outside: tuple = ()

    def record_for(self, precision: float = 0.1, *, level: float = 0.95, entries=None) -> float:
        """Seconds of recording for ``+- precision`` (relative) at ``level`` on every entry named
        in ``entries`` (default: the diagonals of the free matrices): the bound falls as one over
        the square root of the record length when the perturbation goes on with the same
        statistics (``precision.record_seconds``: a precision or a level outside (0, 1) is
        refused in one line)."""
        worst = max(self.relative(entries).values())
        return record_seconds(self.seconds, worst, precision, level=level, where="Bound.record_for")

    def relative(self, entries=None) -> dict:
        """``{label: relative SE bound}`` of ``entries`` (default: the diagonals of the free
        matrices); a one-line error for an entry this bound does not have."""
        rel = dict(zip(self.labels, np.concatenate([v.reshape(-1) for v in self.relative_se.values()]), strict=True))
        entries = [e for e in DIAGONALS if e in rel] if entries is None else list(entries)
        unknown = [e for e in entries if e not in rel]
        if unknown:
            raise ValueError(f"Bound: unknown entries {unknown}; entries of this bound: {self.labels}")
        return {e: float(rel[e]) for e in entries}

    def summary(self) -> str:
        """Lines: what the bound is of, then each free matrix's SE bound and relative SE."""
        lines = [f"Cramér-Rao bound of a {self.seconds:g} s record ({self.reference})"]
        if self.message:
            lines.append("NO BOUND: " + self.message)
        for name in self.se:
            se, rel = np.asarray(self.se[name]), np.asarray(self.relative_se[name])
            lines.append(f"{name}: SE {np.array2string(se, precision=4)}, relative {np.array2string(rel, precision=3)}")
        return "\n".join(lines)


def _no_bound(trial: Trial, f, check: bool, numerics, friction: bool) -> tuple[str, np.ndarray]:
    """``(why no bound holds, or "", the (4,) departure from the linear loop: NaN if unchecked)``:
    a recorded channel without reading noise, or (with ``check``) a hand motion that leaves the
    linear loop's by more than ``NEAR_LINEAR``."""
    departure = np.full(4, np.nan)
    silent = silent_readings(trial)
    if silent:
        return (
            f"the recorded {', '.join(silent)} carry no reading noise in this model (acquisition "
            f"{trial.acquisition!r} and these sensors): a bound would rest on the {kalman.READING_FLOOR[0]:g} m / "
            f"{kalman.READING_FLOOR[2]:g} N reading floor, not on the experiment; predict_se measures it instead"
        ), departure
    if not check:
        return "", departure
    departure = nonlinearity(trial, f, numerics)
    worst = float(np.max(departure[:2]))
    if worst <= NEAR_LINEAR:
        return "", departure
    cause = "joint friction (stick-slip)" if friction else "the amplitude (the robot's nonlinear kinematics)"
    return (
        f"the hand's motion departs from the linear loop's by {worst:.0%} RMS (more than {NEAR_LINEAR:.0%}): "
        f"the loop is not near-linear, through {cause}, and no Cramér-Rao bound holds; predict_se (Monte "
        "Carlo identification through the model) measures this experiment instead"
    ), departure


@functools.partial(jax.jit, static_argnames="numerics")
def _noise_free(trial, f, numerics):
    sim = simulate(replace_unchecked(trial, sensors=quiet(trial.sensors), voluntary=None), f, numerics=numerics)
    return jnp.concatenate([sim.x - trial.x0[None, :], sim.fh], axis=1), sim.diverged


def nonlinearity(trial: Trial, f, numerics=None) -> np.ndarray:
    """``(4,)`` relative RMS departure of the trial's noise-free recording (its friction included;
    ``numerics`` default ``IDENTIFY_NUMERICS``) from its frictionless linearised loop's response;
    inf where it diverges."""
    y, diverged = _noise_free(trial, f, IDENTIFY_NUMERICS if numerics is None else numerics)
    if bool(diverged):
        return np.full(4, np.inf)
    y, y_linear = np.asarray(y), np.asarray(_respond(linear.loop_of(trial), f))
    return np.sqrt(np.sum((y - y_linear) ** 2, axis=0) / np.maximum(np.sum(y_linear**2, axis=0), 1e-300))


# The response from the loop ``linear.loop_of`` already compiled: a second program holding the linearisation
# would compile it again for a scan over the record.
_respond = jax.jit(linear.respond)


def is_near_linear(trial: Trial, f, numerics=None) -> bool:
    """Whether the trial's noise-free hand motion under ``f`` stays within ``NEAR_LINEAR`` of its
    frictionless linearised loop's (one forward simulation; concrete values)."""
    return bool(np.max(nonlinearity(trial, f, numerics)[:2]) <= NEAR_LINEAR)


def silent_readings(trial: Trial) -> list[str]:
    """The recorded outputs (of ``linear.OUTPUTS``) whose reading carries no noise of its own in
    the model (within 10x ``kalman.READING_FLOOR``): there a bound would rest on that floor, an
    artefact (e.g. ``acquisition="interval_mean"`` records the exact mean position)."""
    loop = jax.tree.map(np.asarray, linear.loop_of(trial))
    r = np.diag(kalman.noise_covariances(loop)[1])  # (4,) on the host, from the compiled loop
    floor = np.asarray(kalman.READING_FLOOR)
    return [name for name, v, f in zip(linear.OUTPUTS, r, floor, strict=True) if not v > (10 * f) ** 2]


def has_friction(trial: Trial) -> bool:
    """Whether the trial's robot has Coulomb (or Stribeck) joint friction, the nonlinear part
    (concrete values; viscous friction is linear and stays in the linearised loop)."""
    return trial.friction.has_coulomb()


# The calibrated parameters inside the linearised loop (the viscous friction under either law's name)
LINEAR_CALIBRATED = (
    "robot.inertia",
    "sensors.force_gain",
    "sensors.force_offset",
    "friction.sigma2",
    "friction.viscous",
)


@functools.partial(jax.jit, static_argnames="layout")
def _joint_fisher(layout, trial, f, p):
    """The Fisher information of ``layout``'s internal parameters at ``p`` (any of ``LINEAR`` and
    the viscous friction: ``pack_arm`` takes the arm's only, so ``p`` is given)."""
    _, dy = response_derivative(layout, trial, p, f)
    return kalman.information(kalman.innovations_filter(linear.linearise(trial)), dy)


def calibration_bound(layout: lay.Layout, trial: Trial, f, calibration) -> tuple[np.ndarray, np.ndarray, tuple]:
    """``(I_aa^-1 + G Sigma_c G^T, G Sigma_c G^T, outside)`` on ``layout``'s internal scale: the
    bound of an estimator that holds the calibration at its values (``identify``'s), a two-step
    estimator's (Murphy and Topel): held wrong by ``d c``, the efficient estimate moves by
    ``-G d c``, ``G = I_aa^-1 I_ac`` from the joint information of the arm and the calibrated
    parameters inside the linearised loop. ``outside``: the calibrated labels the linear loop
    lacks (the Coulomb torque), whose share only ``predict_se`` measures."""
    cal = calibration_prior.combine(calibration, trial.friction)
    if trial.acquisition != "instant":  # as identify: the force channel is simulated on instant samples only
        cal = cal.without("sensors.")
    inside = cal.only([n for n in cal.names() if n in LINEAR_CALIBRATED])
    outside = tuple(lab for lab in cal.labels if lab not in inside.labels)
    names = tuple(inside.names())
    joint = lay.Layout(layout.names + names, layout.symmetric + (False,) * len(names))
    info = np.asarray(_joint_fisher(joint, trial, f, lay.pack(joint, trial)))
    n = lay.pack(layout, trial).size
    gain = np.linalg.solve(info[:n, :n], info[:n, n:])
    _, sigma = calibration_prior.internal_covariance(inside, trial)
    share = gain @ sigma @ gain.T
    return np.linalg.inv(info[:n, :n]) + share, share, outside


def crlb(trial: Trial, f, *, free=ARM, symmetric=(), check: bool = True, numerics=None, calibration=None) -> Bound:
    """The Cramér-Rao bound of the free arm parameters from one recording of ``trial`` under the
    perturbation ``f`` ``(N, 2)`` [N] (module docstring).

    Args:
        trial: the planned experiment at its (assumed) true values, with the noise it will meet
            (``Sensors``, ``VoluntaryForce``).
        f: the perturbation ``F_Delta`` ``(N, 2)`` [N].
        free, symmetric: the arm matrices the bound is for (as ``identify``).
        check: run the trial's own noise-free simulation (one forward run, with its friction) and
            give no bound where its hand motion departs from the reference loop's by more than
            ``NEAR_LINEAR`` (stick-slip, or an amplitude that leaves the linear range).
        numerics: the simulation's integrator for that check (default ``IDENTIFY_NUMERICS``).
        calibration: a ``RobotCalibration``, ``ForceCalibration`` or list (as ``identify``'s):
            the bound of an estimator that holds it, its covariance carried (``calibration_bound``;
            the trial's values stay the planned truth's). The Coulomb torque lies outside the
            linearised loop: its share is left out (``Bound.calibration_outside``; ``predict_se``
            measures it).

    A moving arm (``Arm`` with profiles or a path): ``f`` ``(N, 2)`` or draws ``(D, N, 2)``, and the
    answer is ``path_bound.PathBound``, the bound of ONE reach along the path (``R`` reaches:
    ``se / sqrt(R)``; ``reaches_for`` counts them).

    Returns a ``Bound``. Raises a one-line ``ValueError`` for a free name that is not an arm
    matrix, a bad ``f``, or an unstable loop (its spectral radius).
    """
    require_x64("crlb")
    if isinstance(trial, Trial) and trial.arm.moving:  # a reach: the bound of one repetition along its path
        if symmetric or calibration is not None:
            raise ValueError(
                "crlb: for a moving arm, symmetric and calibration are not taken (every knot's full matrix)"
            )
        from .path_bound import path_crlb

        return path_crlb(trial, f, free=free, numerics=numerics)
    layout, f = check_bound_inputs(trial, f, free, symmetric, "crlb")
    if calibration is not None:
        calibration_prior.check_robot(calibration, trial, "crlb")
    if not trial.noisy or not np.any(np.asarray(f) != 0):
        raise ValueError("crlb: the trial has no noise, or f is zero: the bound is 0 or undefined")
    p = lay.pack(layout, trial)
    radius = linear.spectral_radius(linear.loop_of(trial))
    if not radius < 1.0:
        raise ValueError(f"crlb: the loop is unstable (spectral radius {radius:.6f} per period, >= 1)")
    friction = has_friction(trial)
    reference = "the trial's loop without its Coulomb friction" if friction else "the trial's loop"
    # The reasons for no bound come first: they cost a forward run, the information a compile
    # several times longer, which a bound that will not be given should not pay.
    message, departure = _no_bound(trial, f, check, numerics, friction)
    values, g = (np.asarray(v) for v in lay.natural_with_jacobian(layout, p, trial))
    share, outside = np.zeros((values.size, values.size)), ()
    if message:
        info = np.full((p.size, p.size), np.nan)
        cov = np.full((values.size, values.size), np.nan)
    elif calibration is not None:
        cov_p, share_p, outside = calibration_bound(layout, trial, f, calibration)
        info, cov, share = np.linalg.inv(cov_p - share_p), g @ cov_p @ g.T, g @ share_p @ g.T
    else:
        info = np.asarray(_fisher(layout, trial, f))  # one program with fisher_information's
        cov = g @ np.linalg.inv(info) @ g.T
    se = np.sqrt(np.maximum(np.diag(cov), 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.where(values != 0, se / np.abs(values), np.nan)
    return Bound(
        se=lay.unflatten(layout, se),
        values=lay.unflatten(layout, values),
        relative_se=lay.unflatten(layout, rel),
        covariance=cov,
        information=info,
        labels=layout.labels(),
        seconds=f.shape[0] * trial.period,
        reference=reference,
        near_linear=not message,
        nonlinearity=departure,
        spectral_radius=radius,
        message=message,
        calibration_share=share,
        calibration_outside=outside,
    )


def calibration_seconds(trial: Trial, f, calibration, seconds: float, *, free=ARM, widen: float = 0.10) -> float:
    """Seconds of robot-alone recording for every diagonal of the free arm matrices to keep its SE
    bound within ``1 + widen`` of the bound with the robot known, through ``calibration`` (made from
    ``seconds`` of such recording; ``calibration_bound``'s share, the inside of the linear loop).
    A least squares' covariance falls as one over the record, so the share at ``T`` seconds is the
    share at ``seconds`` times ``seconds / T``: ``T = seconds * max_i(share_i / bound_i) / ((1 +
    widen)^2 - 1)``. One-line errors for ``widen`` or ``seconds`` not above 0."""
    if not (np.isfinite(widen) and widen > 0) or not (np.isfinite(seconds) and seconds > 0):
        raise ValueError(f"calibration_seconds: widen and seconds must be > 0, got {widen} and {seconds}")
    layout, f = check_bound_inputs(trial, f, free, symmetric=(), where="calibration_seconds")
    calibration_prior.check_robot(calibration, trial, "calibration_seconds")
    cov_p, share_p, _ = calibration_bound(layout, trial, f, calibration)
    g = np.asarray(lay.natural_jacobian(layout, lay.pack(layout, trial), trial))
    own, share = np.diag(g @ (cov_p - share_p) @ g.T), np.diag(g @ share_p @ g.T)
    diagonals = [i for i, lab in enumerate(layout.labels()) if lab in DIAGONALS]
    worst = max(share[i] / own[i] for i in diagonals)
    return float(seconds * worst / ((1.0 + widen) ** 2 - 1.0))
