"""Intervals entry by entry (issue 50): a one-factor-at-a-time design around one base case,
each cell a ``protocol.Case`` run by ``protocol.study`` (``sweeps/bench_identify_entries.py``).

The base case (``base``): IMBIC through LuGre 0.5 / 0.75 N m, force noise 0.1 N, 2^18-count
encoders, a strong person's force of 0.5 N RMS below 1.5 Hz, 10 s records at the paper's
level 1, the paper's arm at location 2; the arm and ``tau_c`` free, started at the truth.
The cells change one factor: the record (``record-5``, ``record-20`` s), the person's force
(``force-0.1``, ``force-0.3`` N RMS), IMBIC's friction (``friction-0``: the arm alone, and
``friction-1`` N m), the arm (``arm-<L>``: the paper's arm at location L in the base case),
``pd``: PD through 0.3 N m with a 10 N peak, and ``friction-1-arm-4``: the arm at location 4
in the worst cell (``friction-1`` with ``identify`` 2.3.0). Each recording's perturbation is one signal
per cell; the noise is drawn afresh per seed.
"""

from __future__ import annotations

import dataclasses

import jax

import armimp_jax as aj
from armimp_jax import presets

from . import protocol as pr

ARM = pr.ARM


@dataclasses.dataclass(frozen=True)
class Cell:
    """One cell's factors (the base case's by default)."""

    controller: str = "imbic"
    tau_c: float = 0.5
    voluntary: float = 0.5
    seconds: float = 10.0
    location: int = 2
    peak: float | None = None  # [N] per axis; None: the paper's level 1

    def truth(self):
        friction = aj.NO_FRICTION if self.tau_c == 0 else aj.LuGre(self.tau_c, 1.5 * self.tau_c)
        return aj.make_trial(
            aj.kinds.controller_kind(self.controller)(),
            arm=presets.arm(self.location),
            friction=friction,
            sensors=aj.Sensors(force_noise=0.1, encoder_counts=2**18),
            voluntary=aj.VoluntaryForce(self.voluntary, 1.5),
        )

    def free(self) -> tuple:
        return ARM if self.tau_c == 0 else ARM + ("friction.tau_c",)

    def case(self) -> pr.Case:
        truth, free = self.truth(), self.free()
        peak = presets.perturbation_peak(1) if self.peak is None else self.peak
        f = aj.perturbation(jax.random.key(50), int(round(self.seconds * 1000)), peak)

        def recordings(seed):
            rec = pr._record(truth, f, 6000 + seed)
            return [aj.Recording(truth, f, rec.x, rec.fh)], pr._truth_values(truth, free)

        return pr.Case(free, recordings)


BASE = Cell()
CELLS_FACTORS = {
    "base": BASE,
    "record-5": dataclasses.replace(BASE, seconds=5.0),
    "record-20": dataclasses.replace(BASE, seconds=20.0),
    "force-0.1": dataclasses.replace(BASE, voluntary=0.1),
    "force-0.3": dataclasses.replace(BASE, voluntary=0.3),
    "friction-0": dataclasses.replace(BASE, tau_c=0.0),
    "friction-1": dataclasses.replace(BASE, tau_c=1.0),
    **{f"arm-{loc}": dataclasses.replace(BASE, location=loc) for loc in (1, 3, 4)},
    "pd": dataclasses.replace(BASE, controller="pd", tau_c=0.3, peak=10.0),
    # the second arm at the worst cell (2.3.0: friction-1)
    "friction-1-arm-4": dataclasses.replace(BASE, tau_c=1.0, location=4),
}


def settings() -> dict:
    """Every cell's factors (a run folder's settings: naming more cells later extends it)."""
    return {n: dataclasses.asdict(c) for n, c in CELLS_FACTORS.items()}


def cells(names) -> dict:
    """``{name: Case}`` of the cells named (``CELLS_FACTORS``' keys)."""
    return {n: CELLS_FACTORS[n].case() for n in names}


ORACLE_DRAWS = 128  # fresh draws at the truth behind the oracle's reference spread


def oracle(name: str, seeds: int, *, draws: int = 64) -> dict:
    """What an exactly honest linear estimator's SD of z would be on cell ``name``'s first
    ``seeds`` recordings (the recordings' own sampling luck): one fixed statistic (recording 0's,
    as ``identify`` builds it at the truth on ``draws`` draws) and one fixed sensitivity (its
    chord at the truth, without the nuisance prior's rows) applied to every recording, against
    their spread over ``ORACLE_DRAWS`` fresh draws at the truth. Nothing is estimated per
    recording, so the SD of z comes from the recordings alone. ``{"labels", "sd_z", "mean_z",
    "spread", "prior_share", "nuisance"}`` over the arm's internal entries (``spread``: the
    predicted SD, in their units; ``prior_share``: the nuisance prior's moments' share of the
    entry's sandwich variance, against ``spread`` squared (``identify`` scales that part by
    ``1 + 1/R`` more), which a start at the truth never realises), and ``nuisance``:
    ``{label: {"sd_z", "prior_share"}}`` for the other parameters (internal scale: log
    ``tau_c``)."""
    import numpy as np

    from armimp_jax._identification import identify as idm
    from armimp_jax._identification import indirect, search
    from armimp_jax._identification import pool as pl
    from armimp_jax._identification.auxiliary import statistic_labels

    case = CELLS_FACTORS[name].case()
    r = case.recordings(0)[0][0]
    recordings = idm._recordings(r.model, r.f, r.x, r.fh)
    layout, shared, numerics, draws, _, _ = idm._check(recordings, case.free, (), None, "auto", None, draws, 8, 20)
    pool = pl.make_pool(recordings, layout.names, (), shared)
    p, groups = pl.pack(pool), pl.templates(recordings, pool.groups)
    parts, _, _, _ = idm._parts(recordings, pool, groups, p, "auto", numerics, jax.random.key(0), draws, 8)
    n_jac = indirect.draw_counts(r.model, draws, 8)[1]
    problem, part = idm._problem(parts, groups, recordings, pool, p, numerics, n_jac), parts[0]
    jac = search._jacobian(problem, p)
    _, stats, _ = search._binding(problem, p)
    w = search._weights(problem, stats, jac)
    se = np.sqrt(np.diag(search._covariance(problem, jac, stats, problem.n_draws, w)))
    m = stats.shape[1] - problem.prior_index.size
    keys = jax.random.split(jax.random.key(12345), ORACLE_DRAWS)
    q = jax.numpy.asarray(p[part.index])
    ref, diverged = indirect.binding_draws(part.layout, part.model, q, part.f, keys, numerics, part.arm_stat)
    if bool(np.asarray(diverged).any()):
        raise FloatingPointError(f"oracle: a reference draw of cell {name!r} diverged at the truth")
    ref = np.asarray(ref)
    w = np.concatenate([np.asarray(indirect.weights(ref)), np.full(problem.prior_index.size, search.PRIOR_SD**-2)])
    full = search._sensitivity(search._slope(problem, p, se), w)
    sens = full[:, :m]
    spread = np.sqrt(np.diag(sens @ np.cov(ref.T) @ sens.T))
    # the prior's moments in identify's sandwich (Omega's PRIOR_SD^2 block): a start at the truth
    # never draws them, so they widen an SE beyond the spread such recordings show
    prior = search.PRIOR_SD**2 * np.sum(full[:, m:] ** 2, axis=1)
    share = prior / (spread**2 + prior)
    b = []
    for seed in range(seeds):
        rec = case.recordings(seed)[0][0]
        b.append(np.asarray(idm._statistics(part.layout, part.model, rec.f, rec.x, rec.fh, part.arm_stat)))
    z = (np.asarray(b) - ref.mean(axis=0)) @ sens.T / spread
    arm = indirect.arm_index(part.layout)
    rest = np.setdiff1d(np.arange(p.size), arm)
    names = part.layout.labels()  # natural labels: one per internal entry unless a matrix is symmetric
    names = names if len(names) == p.size else [f"p[{j}]" for j in range(p.size)]
    return dict(
        labels=statistic_labels(part.layout)[: arm.size],  # the internal entries, in ``arm``'s order
        sd_z=z.std(axis=0, ddof=1)[arm].tolist(),
        mean_z=z.mean(axis=0)[arm].tolist(),
        spread=spread[arm].tolist(),
        prior_share=share[arm].tolist(),
        nuisance={names[j]: dict(sd_z=float(z[:, j].std(ddof=1)), prior_share=float(share[j])) for j in rest},
    )
