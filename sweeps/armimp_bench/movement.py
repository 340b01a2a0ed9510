"""The arm during a movement (docs/movement.md): the base case, and the classical route's
coverage over Monte Carlo ensembles (``sweeps/bench_movement.py``).

The base case: the paper's arm at location 3 (its matrices), a 12 cm minimum-jerk reach in +y
from that location lasting 0.8 s from 0.4 s, in a 1.6 s record; ``K(t)`` dips to 40% of its still
value at mid-reach, through five knots (the reach's start, quarter, middle, three quarters and
end); ``B`` and ``M`` stay the paper's; PD without friction; the person's force and sensor noise of
the still studies (``study.sweep.coverage.noise``: 0.05 N force noise, 2^18-count encoders, 0.3 N RMS
of the person's own force below 2 Hz); the paper's perturbation at level 1 (2.25 N peak),
drawn anew for every repetition.
"""

from __future__ import annotations

import jax
import numpy as np

import armimp_jax as aj
from armimp_jax import presets
from armimp_jax.study.recording.movement_day import truth  # the arm at the knots: the lab's day's own
from armimp_jax.study.sweep import coverage as cov

ONSET, DURATION, RECORD = 0.4, 0.8, 1.6  # [s]
REACH = (0.0, 0.12)  # [m]
KNOTS = tuple(ONSET + DURATION * f for f in (0.0, 0.25, 0.5, 0.75, 1.0))  # [s]
DIP = (1.0, 0.7, 0.4, 0.7, 1.0)  # K(t_j) / K, a straight fall to mid-reach and back
PEAK = 2.25  # [N] the paper's perturbation level 1


def base_arm(location: int = 3) -> aj.Arm:
    """The base case's moving arm (module docstring)."""
    still = presets.arm(location)
    start = np.asarray(still.endpoint)
    path = aj.MinimumJerk(start=start, end=start + np.asarray(REACH), onset=ONSET, duration=DURATION)
    stiffness = aj.Profile(times=KNOTS, values=np.asarray(DIP)[:, None, None] * np.asarray(still.stiffness))
    return aj.Arm(mass=still.mass, damping=still.damping, stiffness=stiffness, endpoint=path)


def base_trial(controller=None, friction=None, *, noise: bool = True) -> aj.Trial:
    """The base case's trial: PD (``controller``) without friction (``friction``), with the still
    studies' noise (``noise``)."""
    extra = cov.noise() if noise else {}
    return aj.make_trial(
        aj.PD() if controller is None else controller,
        arm=base_arm(),
        friction=aj.NO_FRICTION if friction is None else friction,
        **extra,
    )


def fit_record(fit: aj.results.EnsembleFit) -> dict:
    """An ``EnsembleFit`` as plain lists (a record's row)."""
    names = ("mass", "damping", "stiffness")
    out = {n: np.asarray(getattr(fit, n)).tolist() for n in names}
    out |= {f"{n}_se": np.asarray(getattr(fit, f"{n}_se")).tolist() for n in names}
    return out | dict(dof=fit.dof, warnings=list(fit.warnings))


def fit_names(a) -> list[str]:
    """The fits each ensemble is scored by: ``window:<w>`` for every window [s] of ``a``."""
    return [f"window:{w:g}" for w in a.windows]


def ensemble_row(trial: aj.Trial, seed: int, a) -> dict:
    """One ensemble of the base case (``a.repetitions`` repetitions, its perturbation and noise from
    ``seed``) fitted by every ``fit_names(a)``: a record's row."""
    ens = aj.simulate_ensemble(
        trial,
        aj.signals.PaperNoise(peak=a.peak),
        key=jax.random.key(seed),
        repetitions=a.repetitions,
        samples=int(round(RECORD / trial.period)),
    )
    fits = {}
    for name, window in zip(fit_names(a), a.windows):
        fits[name] = fit_record(aj.estimate_ensemble(ens, knots=KNOTS, window=float(window)))
    return dict(seed=seed, diverged=bool(ens.diverged.any()), fits=fits)


def coverage_summary(rows, true: dict, level: float = 0.95) -> dict:
    """Per fit: over the ensembles of ``rows``, the share of ``level`` intervals (t, the fit's dof)
    that hold the truth, for each knot's K and B diagonals and for M's; the SD of ``z = (estimate -
    truth) / se`` and the mean error over the spread, per entry; pooled coverage of the diagonals."""
    import scipy.stats

    out = {}
    for name in rows[0]["fits"]:
        fits = [r["fits"][name] for r in rows]
        q = scipy.stats.t.ppf(0.5 + level / 2, fits[0]["dof"])
        entry = {}
        for param in ("stiffness", "damping", "mass"):
            e = np.array([f[param] for f in fits])
            s = np.array([f[f"{param}_se"] for f in fits])
            z = (e - true[param]) / s
            diag = (..., [0, 1], [0, 1])
            entry[param] = dict(
                coverage=np.mean(np.abs(z) <= q, axis=0)[diag].tolist(),
                sd_z=z.std(axis=0, ddof=1)[diag].tolist(),
                bias_over_spread=((e.mean(axis=0) - true[param]) / e.std(axis=0, ddof=1))[diag].tolist(),
                spread_over_se=(e.std(axis=0, ddof=1) / s.mean(axis=0))[diag].tolist(),
            )
        pooled = np.concatenate([np.ravel(entry[p]["coverage"]) for p in ("stiffness", "damping")])
        entry["pooled_coverage_kb"] = float(pooled.mean())
        entry["worst_coverage_kb"] = float(pooled.min())
        entry["warned"] = float(np.mean([bool(f["warnings"]) for f in fits]))
        out[name] = entry
    return out


def measured() -> dict:
    """When and where the figures were measured: the date (UTC), the host, its cores, JAX's version."""
    import datetime
    import os
    import platform

    now = datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")
    return dict(date=now, host=platform.node(), cpus=os.cpu_count(), jax=jax.__version__)


def classical_coverage(a, out, *, console=None) -> dict:
    """The classical route's coverage over ``a.ensembles`` ensembles of the base case (options ``a``,
    ``sweeps/bench_movement.py``'s) in run folder ``out``, one record per ensemble (resumable):
    ``{rows, summary}``, also written to ``out/movement_coverage.json`` with the settings."""
    from armimp_jax.study.runs.results import atomic_write_json, stamped

    settings = {k: v for k, v in vars(a).items() if k not in ("out", "ensembles")}

    def make(case):
        return base_trial(), None

    def one(trial, _f, case, seed):
        return ensemble_row(trial, seed, a)

    def report(case, row):
        return f"  ensemble {row['seed']}: fitted by {', '.join(row['fits'])}"

    def finish(run, rows):
        rs = [r for r in rows["base"] if not r["diverged"]]
        summary = coverage_summary(rs, truth(base_trial(), KNOTS)) if rs else {}
        result = dict(ensembles=len(rows["base"]), sound=len(rs), measured=measured(), summary=summary)
        atomic_write_json(run.path / "movement_coverage.json", dict(settings=stamped(settings), **result))
        return result

    spec = cov.Recordings("movement-coverage", settings, ["base"], range(a.ensembles), make, one, report)
    return cov.run_recordings(spec, out, console=console, finish=finish).finished
