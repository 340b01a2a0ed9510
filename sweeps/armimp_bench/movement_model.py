"""The model route during a movement (``identify`` over an ensemble) and the bound along the path,
measured over Monte Carlo ensembles of the base case (``armimp_bench.movement``): coverage, the SD of z,
the spread against ``crlb``, and ``reaches_for`` against the spread (``sweeps/bench_movement.py
--route model``).

Cases: ``imbic`` and ``pd``, without friction; ``imbic-lugre``: IMBIC through LuGre 0.5 / 0.75 N m,
``tau_c`` free (``ensemble_friction``: indirect inference over simulated ensembles); and
``pd-designed``: PD at half its gains, the perturbation moved into the reach (``Envelope``: 0.3
outside it), the best of ``design_reach``'s grid for the base case.
The model's damping is a profile on the stiffness's knots (constant values: the truth), so every
knot's ``B`` and ``K`` are free, with ``M``.
"""

from __future__ import annotations

import jax
import numpy as np

import armimp_jax as aj
from armimp_jax._design import controller_design as cd
from armimp_jax._identification import ensemble_friction as ef
from armimp_jax._identification import ensemble_identify as ei
from armimp_jax._identification import path as ph
from armimp_jax._identification import path_bound as pb
from armimp_jax._identification.linear import without_friction
from armimp_jax._identification.precision import Z95
from armimp_jax.study.sweep import coverage as cov

from .movement import DURATION, KNOTS, ONSET, PEAK, RECORD, base_arm, measured

CASES = ("imbic", "pd", "pd-designed", "imbic-lugre")
LUGRE = (0.5, 0.75)  # [N m] the friction case's Coulomb and stiction torques (tau_c free, tau_s held)
DESIGNED = dict(gain_scale=0.5, rest=0.3)  # design_reach's best for the PD base case (docs/movement.md)
BOUND_DRAWS = 32  # perturbation draws behind the bound's expectation


def _knotted(arm: aj.Arm) -> aj.Arm:
    damping = aj.Profile(times=KNOTS, values=np.broadcast_to(np.asarray(arm.damping), (len(KNOTS), 2, 2)))
    return aj.Arm(mass=arm.mass, damping=damping, stiffness=arm.stiffness, endpoint=arm.endpoint)


def case_trials(case: str) -> tuple[aj.Trial, aj.Trial, tuple]:
    """``(truth, model, free)``: the simulated reach, the model ``identify`` starts from, the free names."""
    controller = aj.PD() if case.startswith("pd") else aj.IMBIC()
    arm = _knotted(base_arm())
    friction = aj.LuGre(*LUGRE) if case.endswith("lugre") else aj.NO_FRICTION
    trial = aj.make_trial(controller, arm=arm, friction=friction, **cov.noise())
    if case == "pd-designed":
        trial = cd.with_gains(trial, cd.initial_log_gains(trial) + np.log(DESIGNED["gain_scale"]))
    return trial, trial, ph.ARM + (("friction.tau_c",) if case.endswith("lugre") else ())


def true_values(case: str) -> np.ndarray:
    """The truth on the case's labels (the knots' entries, then ``tau_c`` per joint where free)."""
    return ei.trial_values(case_trials(case)[0])


def perturbation(case: str):
    """The case's perturbation family: the paper's, or moved into the reach (``pd-designed``)."""
    paper = aj.signals.PaperNoise(peak=PEAK)
    if case != "pd-designed":
        return paper
    return aj.experiment.Envelope(paper, ONSET, ONSET + DURATION, DESIGNED["rest"], 1.0)


def bound_draws(seed: int = 10_000, draws: int = BOUND_DRAWS, case: str = "imbic") -> np.ndarray:
    """``(draws, N, 2)`` the case's perturbation, the bound's expectation's draws."""
    fam, n = perturbation(case), int(round(RECORD / 0.001))
    return np.stack([np.asarray(fam.signal(jax.random.key(seed + i), n, 0.001)) for i in range(draws)])


def ensemble_row(case: str, seed: int, repetitions: int) -> dict:
    """One ensemble of ``case`` identified through the model: the estimate, SEs and diagnostics."""
    truth, model, free = case_trials(case)
    ens = aj.simulate_ensemble(
        truth,
        perturbation(case),
        key=jax.random.key(seed),
        repetitions=repetitions,
        samples=int(round(RECORD / truth.period)),
    )
    # through friction each ensemble's simulated draws its own (independent fits, as the binomial bands assume)
    fit = ei.identify_ensemble(model, ens, free=free, key=jax.random.fold_in(jax.random.key(seed), ef.DRAW_STREAM))
    return dict(
        seed=seed,
        diverged=bool(ens.diverged.any()),
        labels=fit.labels,
        estimate=fit.estimate.tolist(),
        se=fit.se.tolist(),
        start=fit.start.tolist(),
        converged=fit.converged,
        message=fit.message,
        noise_ratio=fit.noise_ratio,
        warnings=list(fit.warnings),
        seconds=fit.seconds,
        steps=fit.steps,
        repetitions=fit.repetitions,
        refreshed_step=getattr(fit, "refreshed_step", None),
        spread_ratio=np.asarray(fit.spread_ratio).tolist(),
    )


def needed(estimates, true, repetitions, precision: float):
    """Reaches the spread needs for ``+-precision`` at 95% per entry: the spread of ``R`` reaches
    scaled as ``1 / sqrt(R - 1)`` (the mean path takes one reach's worth)."""
    eff = np.mean(np.asarray(repetitions, float) - 1.0)
    spread = np.std(estimates, axis=0, ddof=1)
    with np.errstate(divide="ignore"):
        return 1.0 + eff * (Z95 * spread / (precision * np.abs(true))) ** 2


def summary(
    case: str, rows, repetitions: int, bound: pb.PathBound, level: float = 0.95, precision: float = 0.1
) -> dict:
    """Per diagonal entry over the converged ensembles: coverage, SD of z, bias over spread, the
    spread over the bound of ``repetitions`` reaches; the reaches ``reaches_for`` predicts for
    ``precision`` and those the spread needs; pooled coverage."""
    truth, _, _ = case_trials(case)
    ok = [r for r in rows if r["converged"]]  # each fitted its sound reaches
    if not ok:
        return dict(ensembles=len(rows), converged=0)
    labels = ok[0]["labels"]
    true = true_values(case)
    e, s = np.array([r["estimate"] for r in ok]), np.array([r["se"] for r in ok])
    z = (e - true) / s
    q = Z95
    diag = [i for i, lab in enumerate(labels) if lab.endswith(("[0,0]", "[1,1]")) and lab.startswith("arm.")]
    spread = e.std(axis=0, ddof=1)
    reps = np.array([r.get("repetitions", repetitions) for r in ok], dtype=float)
    eff = float(np.mean(reps - 1.0))  # the mean path takes one reach's worth
    bound_se = dict(zip(bound.labels, bound.se / np.sqrt(eff), strict=True))
    predicted = bound.reaches_for(precision, level=level)
    need = needed(e, true, reps, precision)
    entries = {}
    for i in diag:
        lab = labels[i]
        entries[lab] = dict(
            coverage=float(np.mean(np.abs(z[:, i]) <= q)),
            sd_z=float(z[:, i].std(ddof=1)),
            bias_over_spread=float((e[:, i].mean() - true[i]) / spread[i]),
            spread_over_bound=float(spread[i] / bound_se[lab]) if lab in bound_se else None,
            reaches_predicted=predicted.get(lab),
            reaches_from_spread=float(need[i]),
        )
    covered = np.abs(z[:, diag]) <= q
    return dict(
        ensembles=len(rows),
        converged=len(ok),
        pooled_coverage=float(covered.mean()),
        noise_ratio=[float(np.min([r["noise_ratio"] for r in ok])), float(np.max([r["noise_ratio"] for r in ok]))],
        seconds_median=float(np.median([r["seconds"] for r in ok])),
        entries=entries,
    )


def model_coverage(a, out, *, console=None) -> dict:
    """The model route's Monte Carlo over ``a.ensembles`` ensembles of ``a.case`` with ``a.repetitions``
    reaches each, in run folder ``out`` (one record per ensemble, resumable): ``{rows, summary}``,
    written to ``out/movement_model.json`` with the settings (the answer also holds ``rows`` and the
    ``bound``)."""
    from armimp_jax.study.runs.results import atomic_write_json, stamped

    settings = dict(case=a.case, repetitions=a.repetitions, peak=PEAK, bound_draws=BOUND_DRAWS)

    def make(case):
        return None, None

    def one(_t, _f, case, seed):
        return ensemble_row(case, seed, a.repetitions)

    def report(case, row):
        return f"  {case} ensemble {row['seed']}: converged {row['converged']}, {row['seconds']:.0f} s"

    def finish(run, rows):
        truth, _, _ = case_trials(a.case)
        # through friction the bound is the frictionless loop's: what the friction costs shows against it
        bound = pb.path_crlb(without_friction(truth), bound_draws(case=a.case))
        result = dict(measured=measured(), summary=summary(a.case, rows[a.case], a.repetitions, bound))
        atomic_write_json(run.path / "movement_model.json", dict(settings=stamped(settings), **result))
        return dict(result, rows=rows[a.case], bound=bound)

    first = getattr(a, "first", 0)
    spec = cov.Recordings("movement-model", settings, [a.case], range(first, first + a.ensembles), make, one, report)
    return cov.run_recordings(spec, out, console=console, finish=finish).finished
