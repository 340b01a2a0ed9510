"""The coverage matrix: ``identify`` on every controller x friction law it accepts, as a lab
would run it (``sweeps/bench_identify_matrix.py``).

Each cell is one controller kind at its defaults (``pd``, ``imbic``, ``admittance``) and one
friction law (``none``; ``lugre-0.3``: LuGre 0.3 / 0.45 N m; ``cv-0.05``, ``cv-0.3``:
``CoulombViscous`` at 0.05 and 0.3 N m), on the studies' noise (force noise 0.05 N, 2^18-count
encoders, the person's own force 0.3 N RMS below 2 Hz: ``coverage.noise``), 20 s records at
the paper's level-1 perturbation (one signal per cell), the friction known, and the arm free
from a generic start (1 kg, 5 N s/m, 150 N/m on each diagonal, as a lab would guess). Even
seeds record the paper's arm at location 2; odd seeds ``OTHER_ARM``, a non-paper arm with
off-diagonal terms, at location 1's posture. ``<controller>-short`` cells are 8 s records
through LuGre 0.3 N m. ``new-user`` is the new user's lab: admittance through
``CoulombViscous(0.05)``, 25 s at location 1's posture, ``OTHER_ARM`` alone.

A row is ``protocol.one``'s (values, SEs, truth, convergence, warnings); ``summary`` scores a
cell by the issue's rule: coverage over the diagonals, SD of z per entry, z beyond 4, and how
many fits failed or were warned of, each warning counted.
"""

from __future__ import annotations

import dataclasses

import jax
import numpy as np

import armimp_jax as aj
from armimp_jax import presets
from armimp_jax._identification import measured, selfcheck

from . import protocol as pr

ARM = pr.ARM
CONTROLLERS = measured.CONTROLLERS  # the kinds identify's warning names as measured
FRICTIONS = ("none", "lugre-0.3", "cv-0.05", "cv-0.3")  # measured.FRICTIONS: lugre, coulomb_viscous
# a non-paper arm: heavier along x, stiffer than the paper's at location 1, with off-diagonal terms
OTHER_ARM = dict(
    mass=[[1.6, 0.25], [0.2, 1.1]], damping=[[14.0, 3.0], [2.5, 10.0]], stiffness=[[260.0, 60.0], [45.0, 180.0]]
)
GENERIC = dict(mass=np.eye(2), damping=5.0 * np.eye(2), stiffness=150.0 * np.eye(2))
SIGNAL_KEY = 61
Z_FAR = 4.0  # a diagonal z beyond this: at most one in a cell's 300
DISAGREE = "the classical fit of this recording disagrees"  # the cross-check's warning
NOT_TOLD = "the recording barely tells"  # a nuisance's range: the arm's intervals still stand
NOISE = "most likely first: noise"  # an implausible sign within the interval: no warning today


def friction_law(name: str):
    """The law of a cell's friction name."""
    if name == "none":
        return aj.NO_FRICTION
    law, level = name.split("-")
    tau_c = float(level)
    return aj.LuGre(tau_c, 1.5 * tau_c) if law == "lugre" else aj.CoulombViscous(tau_c)


@dataclasses.dataclass(frozen=True)
class Cell:
    """One cell's factors."""

    controller: str
    friction: str
    seconds: float = 20.0
    other_only: bool = False  # every seed on OTHER_ARM (the new user's case)
    location: int = 2  # the paper arm's location (even seeds)
    other_location: int = 1  # OTHER_ARM's posture (odd seeds)

    def arm(self, seed: int) -> aj.Arm:
        if not self.other_only and seed % 2 == 0:
            return presets.arm(self.location)
        return aj.Arm(**OTHER_ARM, endpoint=presets.location_endpoint(self.other_location))

    def trials(self, seed: int):
        """``(truth, start)``: the recording's trial and the lab's model of it, a generic arm."""
        arm = self.arm(seed)
        common = dict(friction=friction_law(self.friction), **pr.cov.noise())
        ctrl = aj.kinds.controller_kind(self.controller)()
        truth = aj.make_trial(ctrl, arm=arm, **common)
        start = aj.make_trial(ctrl, arm=aj.Arm(**GENERIC, endpoint=arm.endpoint), **common)
        return truth, start

    def case(self) -> pr.Case:
        f = aj.perturbation(jax.random.key(SIGNAL_KEY), int(round(self.seconds * 1000)), presets.perturbation_peak(1))

        def recordings(seed):
            truth, start = self.trials(seed)
            rec = pr._record(truth, f, 61_000 + seed)
            return [aj.Recording(start, f, rec.x, rec.fh)], pr._truth_values(truth, ARM)

        return pr.Case(ARM, recordings)


CELLS = {
    **{f"{c}/{fr}": Cell(c, fr) for c in CONTROLLERS for fr in FRICTIONS},
    **{f"{c}-short": Cell(c, "lugre-0.3", seconds=8.0) for c in CONTROLLERS},
    "new-user": Cell("admittance", "cv-0.05", seconds=25.0, other_only=True, location=1),
}


def settings() -> dict:
    """Every cell's factors (a run folder's settings)."""
    return {n: dataclasses.asdict(c) for n, c in CELLS.items()}


def cells(names) -> dict:
    """``{name: Case}`` of the cells named (``CELLS``' keys)."""
    return {n: CELLS[n].case() for n in names}


def _diagonal_z(rows) -> dict:
    """``{label: z (k,)}`` of every arm diagonal over ``rows``."""
    out = {}
    for n in ARM:
        for i in (0, 1):
            e = np.array([r["values"][n][i][i] for r in rows])
            s = np.array([r["se"][n][i][i] for r in rows])
            t = np.array([r["truth"][n][i][i] for r in rows])
            out[f"{n}[{i},{i}]"] = (e - t) / s
    return out


def trusted(row: dict) -> bool:
    """Whether a converged fit's intervals stand: ``intervals_reliable``, or unreliable only for
    what today's code no longer warns of: the classical cross-check at a bound below today's
    (``selfcheck.threshold``), an implausible sign within its 95% interval (rows of an earlier
    run scored as the checks now would; neither moves an estimate)."""
    if row.get("reliable", True):
        return True
    others = [w for w in row["warnings"] if not w.startswith((DISAGREE, NOT_TOLD)) and NOISE not in w]
    bound = selfcheck.threshold(selfcheck.check_draws(row.get("draws", 64)), 12)
    return not others and all(abs(d["z"]) <= bound for d in row.get("disagreements", []))


def summary(rows: list[dict]) -> dict:
    """A cell by the issue's rule. Converged fits without a warning on the intervals are scored;
    the others are counted (``failed``: not converged; ``warned``: converged with
    ``intervals_reliable`` False), each with its first warning or message. Over every converged
    fit too (``*_all``), so a warning that hides wrong answers shows."""
    sound = [r for r in rows if not r["diverged"]]
    converged = [r for r in sound if r["converged"]]
    trusted_ = [r for r in converged if trusted(r)]
    out = dict(
        recordings=len(rows),
        converged=len(converged),
        trusted=len(trusted_),
        failed=[dict(seed=r["seed"], why=r["message"]) for r in sound if not r["converged"]],
        warned=[dict(seed=r["seed"], why=(r["warnings"] or [""])[-1]) for r in converged if not trusted(r)],
    )
    for tag, group in (("", trusted_), ("_all", converged)):
        if len(group) < 2:
            continue
        z = _diagonal_z(group)
        every = np.concatenate(list(z.values()))
        out[f"coverage{tag}"] = float(np.mean(np.abs(every) <= pr.cov.Z95))
        out[f"sd_z{tag}"] = {k: float(np.std(v, ddof=1)) for k, v in z.items()}
        out[f"beyond_4{tag}"] = int(np.sum(np.abs(every) > Z_FAR))
        out[f"max_abs_z{tag}"] = float(np.max(np.abs(every)))
    out["mean_time_s"] = float(np.mean([r["time_s"] for r in sound])) if sound else None
    return out


WARNED = "refused or warned"  # a cell the tool declines: the honest outcome, listed


def verdict(s: dict) -> str:
    """The issue's bands on one cell's summary: ``"pass"``; ``"refused or warned ..."`` where most
    fits failed or were warned of (each with its reason) and no trusted fit lies beyond 4 SE (a
    cell the tool declines, honestly); or what fails."""
    declined = s["recordings"] - s["trusted"]
    if declined > s["recordings"] / 2:
        if s.get("beyond_4", 0) > 0:
            return f"{declined} of {s['recordings']} declined, but {s['beyond_4']} trusted diagonal z beyond 4"
        return f"{WARNED} on {declined} of {s['recordings']} recordings"
    if "coverage" not in s:
        return "too few trusted fits"
    fails = []
    if not 0.92 <= s["coverage"] <= 0.98:
        fails.append(f"coverage {s['coverage']:.3f}")
    bad = {k: v for k, v in s["sd_z"].items() if not 0.8 <= v <= 1.25}
    if bad:
        fails.append("SD of z " + ", ".join(f"{k} {v:.2f}" for k, v in bad.items()))
    if s["beyond_4"] > 1:
        fails.append(f"{s['beyond_4']} diagonal z beyond 4")
    return "pass" if not fails else "; ".join(fails)


_SYMBOL = dict(mass="M", damping="B", stiffness="K")


def _line(name: str, s: dict, verdict: str) -> str:
    if "coverage" not in s:
        return f"| {name} | {s['converged']}/{s['recordings']} | {s['trusted']} | - | - | - | {verdict} |"
    sd = ", ".join(f"{_SYMBOL[k.split('.')[1].split('[')[0]]}{k[-4]}{k[-2]} {v:.2f}" for k, v in s["sd_z"].items())
    return (
        f"| {name} | {s['converged']}/{s['recordings']} | {s['trusted']} | {s['coverage']:.3f} "
        f"({s.get('coverage_all', float('nan')):.3f}) | {sd} | {s['beyond_4']} (max {s['max_abs_z']:.1f}) | {verdict} |"
    )


def table_lines(summaries: dict) -> list[str]:
    """The cells' markdown table (``summary`` per cell, with its ``verdict``), then every fit
    failed or warned of, with why."""
    lines = [
        "| cell | converged | trusted | coverage, diagonals (all converged) | SD of z | z beyond 4 | verdict |",
        "|---|---|---|---|---|---|---|",
    ]
    lines += [_line(name, s, verdict(s)) for name, s in summaries.items()]
    for name, s in summaries.items():
        lines += [f"{name} seed {r['seed']} {kind}: {r['why']}" for kind in ("failed", "warned") for r in s[kind]]
    return lines
