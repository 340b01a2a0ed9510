"""The model route over an ensemble of reaches: ``identify(model, ensemble=...)``.

Each repetition records ``y_r = mu(theta, f_r) + v_r`` (``path_bound.py``). Subtracting the
ensemble's mean at each sample makes the mean path a free nuisance (a fixed effect per sample);
what is left is fitted by generalised least squares with the noise whitened by the time-varying
Kalman filter of the loop linearised along the path (``path.py``):

    min_theta sum_r || W(theta) [ (y_r - y_bar) - (mu(theta, f_r) - mu_bar(theta)) ] ||^2,

by chord iterations from the classical route's answer: each holds the Jacobian and the filter
at its start (one binding serves every repetition and every step) until its step is below
``TOLERANCE`` SE, and the next starts from a loop linearised anew at that answer, until the step
from there is below ``REFRESH_TOLERANCE`` SE. So the answer solves ``J(p)^T W(p) r(p) = 0``, the
GLS with the loop linearised at the estimate, not at the start (a single chord held at the
classical answer stopped 0.1-0.5 SE short of it). The covariance is ``(sum_r J_r^T J_r)^-1`` at
the answer (the bound at the estimate); the step still left is reported (``refreshed_step``, in
SEs) and warned of above ``REFRESH_WARN``.

The bound is not the spread where the loop bends across the hand's excursions: PD at half its
gains spread 1.2-1.3 times the bound on mid-reach ``K_yy`` and its intervals held 0.86-0.90
(docs/movement.md, section 7). So the intervals are checked on each call: ``CHECK_DRAWS`` (``ensemble_search.py``)
ensembles are simulated at the answer (the lab's perturbations, the model's noise), each refitted
by the chord held there, and each entry's interval is widened to their RMS error about the answer
where it exceeds the bound (``spread_ratio``). The whitened
residuals' variance is checked against the model's noise (1 when the trial's
noise levels are the lab's): above it the intervals are widened by it and a warning says why.

Friction: through it the noise-free loop is not the mean of the noisy one (this GLS walked off the
classical answer under IMBIC through LuGre 0.5 N m: M 12-17% low on 5 of 5 ensembles of 40 reaches),
so a model with friction goes to ``ensemble_friction.py``: indirect inference over ensembles
simulated through the friction, this GLS step (held at the start) its arm's statistic, ``tau_c``
a nuisance with the still route's prior.
"""

from __future__ import annotations

import dataclasses
import importlib.metadata
import time

import jax
import jax.numpy as jnp
import numpy as np
from scipy.stats import norm

from .._checks import require_x64
from .._estimation.ensemble import Ensemble
from .._estimation.ensemble_fit import estimate_ensemble
from .._pytree import replace_unchecked
from .._simulate import Trial
from . import ensemble_friction as ef
from . import ensemble_search as es
from . import layout as lay
from . import path as ph
from .bound import has_friction
from .indirect import IDENTIFY_NUMERICS

MIN_REPETITIONS = 8  # below this the ensemble's mean path (a nuisance per sample) takes too much of the data
MEASURED_REPETITIONS = 40  # the Monte Carlo's ensembles (docs/movement.md); fewer are warned of
REFRESH_WARN = 0.1  # [SE] a step the refreshed Jacobian would still take beyond this is warned of
# The pairs (controller, friction or "none") whose intervals the Monte Carlo measured over ensembles.
MEASURED = {("imbic", "none"), ("pd", "none"), ("imbic", "lugre")}
# Through friction: the controllers measured there (under PD through LuGre 0.5 N m the search did not
# end on any of 8 ensembles), the laws, and the parameters of theirs that may be free (ensemble_friction.py).
FRICTION_CONTROLLERS = tuple(sorted({controller for controller, law in MEASURED if law != "none"}))
FRICTION_LAWS = ("LuGre",)
FRICTION_FREE = ("friction.tau_c",)


@dataclasses.dataclass(frozen=True)
class EnsembleIdentification:
    """``identify``'s answer over an ensemble (host values).

    ``labels`` (``"arm.stiffness@t=0.6[0,0]"``, row by row per knot), ``estimate``, ``se``,
    ``start`` ``(n,)``; ``covariance`` ``(n, n)``; ``converged``, ``steps``, ``message``;
    ``refreshed_step``: the largest step, in SEs, the Jacobian and filter at the answer would take
    (NaN through friction, whose search ends on its own binding);
    ``spread_ratio`` ``(n,)``: each entry's RMS error over ensembles simulated at the answer (about
    the answer, their truth) over its SE on the bound (the intervals are widened by it where above 1;
    NaN through friction, whose intervals come from its simulated ensembles, where the search
    failed, or where fewer than half of them refit); ``check_refits``: how many refit;
    ``noise_ratio``: the whitened residuals' variance over the model's (1 when the trial's noise is
    the lab's; the intervals are widened by it above 1; through friction, the whitened deviations'
    energy over the simulated ensembles', mostly the friction's: reported, not widened by);
    ``warnings`` in a lab's terms;
    ``repetitions``, ``seconds`` (wall time), ``settings`` (everything the call was given, and the version)."""

    labels: list
    estimate: np.ndarray
    se: np.ndarray
    start: np.ndarray
    covariance: np.ndarray
    converged: bool
    steps: int
    message: str
    noise_ratio: float
    refreshed_step: float
    spread_ratio: np.ndarray
    check_refits: int
    warnings: tuple
    repetitions: int
    seconds: float
    settings: dict

    def interval(self, label: str, level: float = 0.95) -> tuple[float, float]:
        """The ``level`` interval of one entry (normal: the information of every repetition)."""
        if label not in self.labels:
            raise ValueError(f"EnsembleIdentification: unknown entry {label!r}; entries: {self.labels}")
        i, z = self.labels.index(label), float(norm.ppf(0.5 + level / 2))
        return float(self.estimate[i] - z * self.se[i]), float(self.estimate[i] + z * self.se[i])

    def table(self, level: float = 0.95):
        """A pandas table: each entry's estimate, SE and ``level`` interval."""
        import pandas as pd

        z = float(norm.ppf(0.5 + level / 2))
        return pd.DataFrame(
            {
                "entry": self.labels,
                "estimate": self.estimate,
                "se": self.se,
                "low": self.estimate - z * self.se,
                "high": self.estimate + z * self.se,
            }
        )

    def summary(self, level: float = 0.95) -> str:
        state = "converged" if self.converged else f"NOT converged: {self.message}"
        lines = [f"identify over {self.repetitions} reaches: {state} in {self.steps} steps, {self.seconds:.0f} s"]
        z = float(norm.ppf(0.5 + level / 2))
        for label, v, s in zip(self.labels, self.estimate, self.se, strict=True):
            if label.endswith(("[0,0]", "[1,1]")) or label.startswith("friction"):
                lines.append(f"  {label:32s} {v:10.4g}  [{v - z * s:.4g}, {v + z * s:.4g}]")
        lines += [f"WARNING: {w}" for w in self.warnings]
        return "\n".join(lines)


def _recorded(ensemble: Ensemble, trial: Trial) -> np.ndarray:
    return np.concatenate([ensemble.x - np.asarray(trial.x0), ensemble.fh], axis=2)


def _check(model, ensemble, free, where: str) -> tuple[Ensemble, ph.KnotLayout]:
    if not isinstance(model, Trial):
        raise ValueError(f"{where}: over an ensemble, model must be a Trial (the reach, its profiles' knots free)")
    if not isinstance(ensemble, Ensemble):
        raise ValueError(
            f"{where}: ensemble must be an Ensemble (simulate_ensemble, load_ensemble), got {type(ensemble).__name__}"
        )
    if ensemble.f_delta is None:
        raise ValueError(f"{where}: the ensemble holds no perturbations: the model route needs each reach's F_Delta")
    if abs(ensemble.period - float(model.period)) > 1e-12:
        raise ValueError(
            f"{where}: the ensemble is sampled every {ensemble.period:g} s and the model's loop every "
            f"{float(model.period):g} s"
        )
    sound = ensemble.sound()
    if sound.repetitions < MIN_REPETITIONS:
        raise ValueError(
            f"{where}: {sound.repetitions} sound repetitions; the model route needs at least {MIN_REPETITIONS} "
            "(the ensemble's "
            "mean path takes one repetition's worth of the data)"
        )
    layout = ph.knot_layout(model, _split_free(model, free, where)[0], where=where)
    ph.check_reach_model(model, layout, sound.samples, where)
    if np.allclose(sound.f_delta, sound.f_delta[:1]):
        raise ValueError(
            f"{where}: every reach has the same perturbation: less the ensemble's mean nothing is left to tell "
            "the arm; "
            "draw each reach's perturbation anew"
        )
    if not model.noisy:
        raise ValueError(f"{where}: the model has no noise (Sensors, VoluntaryForce): the intervals rest on it")
    return sound, layout


def _split_free(model: Trial, free, where: str) -> tuple[tuple, tuple]:
    """``(arm names, friction names)`` of ``free``; friction's only through a law the route has measured."""
    free = (free,) if isinstance(free, str) else tuple(free)
    friction = tuple(n for n in free if n.startswith("friction."))
    if friction and not has_friction(model):
        raise ValueError(f"{where}: {friction[0]} is free but the model has no friction")
    law = type(model.friction).__name__
    if has_friction(model) and _controller_name(model) not in FRICTION_CONTROLLERS:
        raise ValueError(
            f"{where}: over an ensemble, the route through friction is measured under "
            f"{', '.join(c.upper() for c in FRICTION_CONTROLLERS)} alone, not under {type(model.controller).__name__} "
            "(PD's search did not settle; the admittance controllers are not measured: docs/movement.md): use "
            "estimate_ensemble (the classical route), or identify each still posture"
        )
    if has_friction(model) and (law not in FRICTION_LAWS or not set(friction) <= set(FRICTION_FREE)):
        raise ValueError(
            f"{where}: over an ensemble, the route through friction is measured for {', '.join(FRICTION_LAWS)} with "
            f"{', '.join(FRICTION_FREE)} free (a nuisance, freed where not named), got {law} with "
            f"{list(friction) or 'nothing'} free; "
            "use estimate_ensemble (the classical route), or identify each still posture"
        )
    return tuple(n for n in free if not n.startswith("friction.")), friction


def _classical_start(layout: ph.KnotLayout, model: Trial, ensemble: Ensemble) -> np.ndarray:
    """The classical route's answer on ``layout``'s knots (the model's values where it cannot run)."""
    p = np.asarray(ph.pack(layout, model)).copy()
    knots = sorted({t for ks in layout.knots for t in ks})
    try:
        fit = estimate_ensemble(ensemble, knots=knots or None)
    except ValueError:  # too few reaches, or knots the window cannot hold: the model's own values
        return p
    at = 0
    for name, ks in zip(layout.names, layout.knots):
        attr = name.split(".")[1]
        values = fit.mass[None] if attr == "mass" else getattr(fit, attr)
        block = (
            values if attr == "mass" else np.stack([values[knots.index(t)] for t in ks]) if ks else values.mean(0)[None]
        )
        n = 4 * block.shape[0]
        p[at : at + n] = block.reshape(-1)
        at += n
    return p


def trial_values(trial: Trial) -> np.ndarray:
    """The trial's own values on the model route's labels: every knot's entries, then ``tau_c`` per
    joint where the trial has Coulomb friction (the route frees it there)."""
    arm = np.asarray(ph.pack(ph.knot_layout(trial, ph.ARM), trial))
    return np.concatenate([arm, np.asarray(trial.friction.tau_c)]) if has_friction(trial) else arm


def _controller_name(model: Trial) -> str:
    return type(model.controller).__name__.lower()


def _warnings(model, sound, noise_ratio, refreshed, check=None, labels=()) -> list[str]:
    out = []
    kind = (_controller_name(model), type(model.friction).__name__.lower() if has_friction(model) else "none")
    if kind not in MEASURED:
        out.append(
            f"the model route over an ensemble has not been measured by Monte Carlo under "
            f"{type(model.controller).__name__}: its intervals "
            "rest on this call's check (ensembles refitted at the answer); treat them as provisional (docs/movement.md)"
        )
    if sound.repetitions < MEASURED_REPETITIONS / 2:
        out.append(
            f"{sound.repetitions} reaches: the intervals were measured with {MEASURED_REPETITIONS}; "
            "record more reaches "
            "(reaches_for says how many a precision needs)"
        )
    if refreshed > REFRESH_WARN:
        out.append(
            f"the answer is {refreshed:.2f} SE from where the Jacobian at it points (more than {REFRESH_WARN:g}): the "
            "fit is not linear across its intervals; record more reaches"
        )
    out += es.check_warnings(check, labels)
    if noise_ratio > 1.5 or noise_ratio < 0.5:
        widened = "" if has_friction(model) else ": the intervals are widened by it where above 1"
        out.append(
            f"the reaches' noise is {noise_ratio:.2f} times the model's (its person's force and sensor noise)"
            f"{widened}; set the trial's Sensors and VoluntaryForce to the lab's"
        )
    return out


def identify_ensemble(
    model: Trial, ensemble: Ensemble, *, free=ph.ARM, numerics=None, max_steps: int = 12, start=None, key=None
) -> EnsembleIdentification:
    """The arm's ``M``, and ``B`` and ``K`` at every knot of the model's profiles, from an ensemble
    of reaches through the model (module docstring).

    Args:
        model: the reach (``make_trial`` with a moving arm): every fixed setting, the noise levels
            the intervals rest on, the profiles' knots (each knot's matrix is free).
        ensemble: the reaches (``simulate_ensemble``, ``load_ensemble``, ``Ensemble``), with each
            one's perturbation; diverged repetitions are left out.
        free: arm matrices (each knot's, where the model's matrix is a profile).
        numerics: the simulation's integrator (default ``IDENTIFY_NUMERICS``).
        max_steps: Gauss-Newton steps at most (without friction: per chord, at most 8, and a chord from
            each of up to ``MAX_REFRESHES`` re-linearisations).
        start: ``(n,)`` start on ``labels`` (default: the classical route's answer on the knots; through
            friction, then the model's ``tau_c`` per joint, the nuisance prior's centre).
        key: the simulated ensembles' noise: through friction, the indirect inference's; without,
            the check of the intervals' (default: a fixed stream; every call the same draws).
    """
    require_x64("identify")
    t0 = time.perf_counter()
    sound, layout = _check(model, ensemble, free, "identify")
    numerics = numerics or IDENTIFY_NUMERICS
    f = jnp.asarray(sound.f_delta)
    if has_friction(model):
        return _through_friction(model, sound, layout, free, numerics, max_steps, start, t0, key)
    p_start = _classical_start(layout, model, sound) if start is None else np.asarray(start, dtype=np.float64)
    y = jnp.asarray(_recorded(sound, model))
    p, steps, converged, message, lin = es.search(layout, model, p_start, f, y, numerics, min(max_steps, 8))
    cov, noise_ratio, refreshed = np.full((p.size, p.size), np.nan), float("nan"), float("nan")
    spread, refits = np.full(p.size, np.nan), 0
    if not message:
        cov, noise_ratio, refreshed = es.at_answer(lin, y, sound.repetitions)
        # the check's own stream, whatever the key: never the lab's draws (simulate_ensemble(key=key))
        base = jax.random.fold_in(jax.random.key(0) if key is None else key, es.CHECK_STREAM)
        spread, refits = es.spread_ratio(layout, model, lin, f, numerics, base)
        widen = np.where(np.isfinite(spread), np.maximum(spread, 1.0), 1.0)
        cov = cov * np.outer(widen, widen)
    check = (spread, refits)
    warnings = () if message else tuple(_warnings(model, sound, noise_ratio, refreshed, check, layout.labels()))
    return _result(
        layout.labels(),
        p,
        cov,
        p_start,
        (converged, steps, message),
        (noise_ratio, refreshed, spread, refits),
        warnings,
        sound,
        dict(
            free=free, numerics=numerics, max_steps=min(max_steps, 8), check_draws=es.CHECK_DRAWS, key=key is not None
        ),
        t0,
    )


def _result(labels, p, cov, p_start, state, diagnostics, warnings, sound, settings, t0):
    free = settings["free"]
    settings = dict(settings, free=[free] if isinstance(free, str) else list(free), numerics=repr(settings["numerics"]))
    converged, steps, message = state
    noise_ratio, refreshed, spread, refits = diagnostics
    return EnsembleIdentification(
        labels=labels,
        estimate=p,
        se=np.sqrt(np.maximum(np.diag(cov), 0.0)),
        start=p_start,
        covariance=cov,
        converged=converged,
        steps=steps,
        message=message,
        noise_ratio=noise_ratio,
        refreshed_step=refreshed,
        spread_ratio=spread,
        check_refits=refits,
        warnings=warnings,
        repetitions=sound.repetitions,
        seconds=time.perf_counter() - t0,
        settings=settings | dict(version=importlib.metadata.version("armimp_jax")),
    )


def _through_friction(model, sound, knots, free, numerics, max_steps, start, t0, key=None):
    """The route through friction (``ensemble_friction.py``): indirect inference over simulated ensembles;
    ``tau_c`` freed as a nuisance where ``free`` does not name it."""
    friction = lay.make_layout(_split_free(model, free, "identify")[1] or FRICTION_FREE, friction=model.friction)
    n_arm = knots.size()
    held = model
    if start is not None:
        start = np.asarray(start, dtype=np.float64)
        if start.shape != (n_arm + 2,):
            raise ValueError(f"identify: start has {start.size} entries; the fit's labels are {n_arm + 2}")
        held = replace_unchecked(model, friction=replace_unchecked(model.friction, tau_c=start[n_arm:]))
    try:
        tau_c = np.asarray(lay.pack(friction, held))
    except ValueError as err:
        raise ValueError(f"{err} (over an ensemble through friction, tau_c is always freed: a nuisance)") from None
    p_start = np.concatenate([_classical_start(knots, model, sound) if start is None else start[:n_arm], tau_c])
    f = jnp.asarray(sound.f_delta)
    stat = ef.make_statistic(knots, model, p_start[:n_arm], f, numerics)
    # the draws' own stream, whatever the key: never the lab's (simulate_ensemble(key=key))
    base = jax.random.fold_in(jax.random.key(0) if key is None else key, ef.DRAW_STREAM)
    keys = jnp.stack([jax.random.split(jax.random.fold_in(base, d), sound.repetitions) for d in range(ef.DRAWS)])
    route = ef.Route(knots, friction, model, f, stat, keys, numerics)
    contrib, energy = ef.observed(stat, model, f, jnp.asarray(_recorded(sound, model)))
    answer = ef.search(route, p_start, ef.statistic_of(route, contrib), float(energy), max_steps)
    value, jac = lay.natural_with_jacobian(friction, jnp.asarray(answer.p[n_arm:]), model)
    to_natural = np.eye(answer.p.size)
    to_natural[n_arm:, n_arm:] = np.asarray(jac)
    estimate = np.concatenate([answer.p[:n_arm], np.asarray(value)])
    cov = to_natural @ answer.covariance @ to_natural.T
    start_natural = np.concatenate(
        [p_start[:n_arm], np.asarray(lay.natural(friction, jnp.asarray(p_start[n_arm:]), model))]
    )
    warnings = tuple(_warnings(model, sound, answer.noise_ratio, 0.0)) if not answer.message else ()
    state = (answer.converged, answer.steps, answer.message)
    settings = dict(
        free=free,
        numerics=numerics,
        max_steps=max_steps,
        draws=ef.DRAWS,
        chord_draws=ef.CHORD_DRAWS,
        key=key is not None,
    )
    labels = knots.labels() + friction.labels()
    diagnostics = (answer.noise_ratio, float("nan"), np.full(estimate.size, np.nan), 0)
    return _result(labels, estimate, cov, start_natural, state, diagnostics, warnings, sound, settings, t0)


def identify_over(
    model, ensemble, x, fh, calibration, *, free, numerics, max_steps, key=None
) -> EnsembleIdentification:
    """``identify(model, ensemble, ...)``: refuses what the route does not take, then ``identify_ensemble``."""
    if x is not None or fh is not None or calibration is not None:
        raise ValueError("identify: with an ensemble, x, fh and calibration stay None (each reach holds its own)")
    return identify_ensemble(model, ensemble, free=free, numerics=numerics, max_steps=min(max_steps, 12), key=key)
