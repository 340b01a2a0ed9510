"""Why four of the paper's claims are only "partly" reproduced: the claim explanations as a
specification of the study engine (``ExplainSettings``), and their Markdown.

Each experiment (``paper._experiments``) changes one assumption of the reproduction and keeps
the rest (the paper's arms, friction levels, gains, perturbation filter and Table 4 Welch
settings; seed ``s`` draws its perturbation from ``fold_in(PRNGKey(0), s)`` like the
reproduction, so seeds 0-2 are the reproduction's trials). A trial is one run of one
experiment: its point (``Run.point``, the one trial description, a ``study.Point``), its
``trial`` simulated with ``SWEEP_NUMERICS`` (ARK3, 20 substeps); ``measure``
keeps its metrics (``study.sweep.metrics.trial_metrics`` per Welch segment, with where the
coherence minimum falls; how often the joints slide; the perturbation's torque against
stiction; the bristle load) as the record's meta. ``explain`` runs it on ``engine.run`` (a
folder holds one study: resumable, its records checked) and writes ``claims_explained.md``.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time
from collections.abc import Callable

import numpy as np

from .._estimation.estimate import estimate
from .._model.robot import MIT_MANUS, jacobian
from .._simulate import stack_trials
from .._solver.numerics import SWEEP_NUMERICS
from ..presets import arm
from ..study.runs import engine
from ..study.runs.console import Console
from ..study.runs.results import ResultsError, atomic_write_text, describe_difference, settings_key, stamped
from ..study.runs.runfolder import StudyRun, warn_stderr
from ..study.schema.points import Point
from ..study.sweep.metrics import trial_metrics
from ._experiments import BASE_SEED, FULL, QUICK, SLIDE_RATE, Experiments, Run, Setup

MARKDOWN = "claims_explained.md"


@dataclasses.dataclass(frozen=True)
class ExplainSettings(engine.SimulationSpec):
    """The claim explanations: the ``quick`` setup (6 s / 12 s records, 1024 / 4096-sample
    segments, 2 seeds) or the full one, and the experiments to run (``only``: letters of
    ``ABCDE``). A specification of the study engine: a trial is ``(letter, index)``, the
    index-th run of that experiment."""

    KIND = "claims"
    FORMAT = 1
    NOUN = "claims study"
    base_seed = BASE_SEED

    quick: bool = False
    only: str = "ABCDE"

    @property
    def setup(self) -> Setup:
        return QUICK if self.quick else FULL

    def validate(self) -> None:
        bad = set(self.only) - set(Experiments.LETTERS)
        if bad or not self.only:
            raise ValueError(f"only takes letters of ABCDE, got {self.only!r}")

    def run_settings(self) -> dict:
        return stamped(dict(quick=self.quick, only=self.only, setup=dataclasses.asdict(self.setup)))

    def run_extra(self) -> dict:
        return dict(wall_s=0.0)

    describe = staticmethod(describe_difference)

    @classmethod
    def from_saved(cls, saved, *, where: str = "run.json") -> ExplainSettings:
        try:
            return cls(quick=saved["quick"], only=saved["only"])
        except (KeyError, TypeError) as err:
            raise ResultsError(f"{where}: not the settings of a claims study ({err})") from None

    @functools.cached_property
    def plan(self) -> dict[str, tuple[list[Run], dict, list[dict]]]:
        """``{letter: (runs, segments, points)}`` of the experiments asked for, in the order
        asked (``segments``: record length [s] -> Welch segments; a run's point with the first)."""
        experiments = Experiments(self.setup)
        plan = {}
        for letter in self.only:
            runs, segments = experiments.runs(letter)
            plan[letter] = runs, segments, [r.point(segments[r.seconds][0]) for r in runs]
        return plan

    def run(self, trial) -> tuple[Run, list[int], Point]:
        """``(run, its Welch segments, its point)`` of a trial."""
        letter, k = trial
        runs, segments, points = self.plan[letter]
        return runs[k], segments[runs[k].seconds], points[k]

    # --- the engine's specification ---

    def trials(self) -> list[tuple[str, int]]:
        return [(letter, k) for letter, (runs, _, _) in self.plan.items() for k in range(len(runs))]

    def trial_record(self, trial) -> tuple[str, dict]:
        r, segments, point = self.run(trial)
        settings = dict(experiment=trial[0], point=point.settings, seed=r.seed, segments=segments)
        settings["base_seed"] = self.base_seed
        settings["numerics"] = SWEEP_NUMERICS.settings()
        return f"{trial[0]}{trial[1]:04d}-{settings_key(dict(point=point.settings))[:8]}-s{r.seed}", stamped(settings)

    def group(self, trial) -> tuple:
        return trial[0], self.run(trial)[2].group

    def samples(self, trial) -> int:
        return self.run(trial)[2].samples

    def build(self, batch, signals: engine.Perturbations) -> engine.Simulation:
        runs = [self.run(t) for t in batch]
        n = runs[0][2].samples
        f_delta = np.stack([signals(r.seed, n, r.peak) for r, _, _ in runs])
        return engine.Simulation(stack_trials([p.trial for _, _, p in runs]), f_delta, SWEEP_NUMERICS)

    def measure(self, batch, built, sim, outcome) -> list[tuple[dict, dict]]:
        out = []
        for j, trial in enumerate(batch):
            r, segments, point = self.run(trial)
            out.append(({}, dict(metrics=measure(r, point, built.f_delta[j], sim, j, segments))))
        return out


def measure(r: Run, point: Point, f_delta, sim, j: int, segments) -> dict:
    """Trial ``j`` of a batch's simulation: whether it diverged, its sliding share, its
    perturbation-torque share over stiction, its bristle load, and per Welch segment the
    study's ``trial_metrics`` with the coherence minimum and where it falls."""
    q = np.asarray(sim.q[j])
    m = dict(diverged=bool(sim.diverged[j]))
    m["slide"] = float(np.mean(np.any(np.abs(np.diff(q, axis=0)) * 1000.0 > SLIDE_RATE, axis=1)))
    # the perturbation's own joint torque J(q0)^T F_Delta against the stiction torque
    tau = np.abs(f_delta @ np.asarray(jacobian(q[0], MIT_MANUS)))  # (N, 2): J^T F per sample
    lugre = point.friction
    tau_s = float(np.max(lugre.tau_s))
    m["over_stiction"] = float(np.mean(np.any(tau > tau_s, axis=1))) if tau_s > 0 else float("nan")
    # bristle load sigma0 |z| / tau_s: ~0 a linear spring, -> 1 at breakaway (LuGre's z' = v - sigma0 |v| z / g)
    load = np.max(np.abs(np.asarray(sim.z[j])) * np.asarray(lugre.sigma0), axis=1) / tau_s if tau_s > 0 else None
    m["load_p95"] = float(np.percentile(load, 95)) if load is not None else float("nan")
    for seg in segments:
        m[f"w{seg}"] = estimate_metrics(r, f_delta, sim, j, seg)
    return m


def estimate_metrics(r: Run, f_delta, sim, j: int, seg: int) -> dict:
    """``trial_metrics`` of trial ``j``'s estimate with ``seg``-sample segments (overlap 3/4),
    plus the lowest multiple coherence of x, its bin, and its bin below 2 Hz."""
    est = estimate(f_delta, sim.x[j], sim.fh[j], nperseg=seg, noverlap=3 * seg // 4, errors=False)
    arrays = {k: np.asarray(v) for k, v in est._asdict().items()}
    f = arrays["f"]
    mm = trial_metrics(f, arrays["Z"], arrays, arm(r.location))
    coh = arrays["coh_multiple_x"]
    k = np.unravel_index(np.argmin(coh), coh.shape)
    low = f < 2.0
    mm["coh_min"] = float(coh.min())
    mm["coh_min_f"] = float(f[k[0]])
    mm["coh_min_low_f"] = float(f[low][np.argmin(coh[low].min(axis=1))]) if low.any() else float("nan")
    return mm


def _nan(obj):
    """A record's metrics as measured: strict JSON wrote NaN as null."""
    if isinstance(obj, dict):
        return {k: _nan(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_nan(v) for v in obj]
    return math.nan if obj is None else obj


def markdown(settings: ExplainSettings, run: StudyRun, *, warn: Callable[[str], None] = warn_stderr) -> list[str]:
    """The study's Markdown: one table per experiment, from the run's checked records (an
    experiment with a record missing is left out, named in a line)."""
    records, _ = engine.records(settings, run, warn=warn)
    experiments = Experiments(settings.setup)
    lines = []
    for letter, (runs, _, _) in settings.plan.items():
        found = [records.get((letter, k)) for k in range(len(runs))]
        if not all(found):
            lines += [f"### {letter}: {sum(r is None for r in found)} of {len(runs)} trials missing", ""]
            continue
        title, intro, table = experiments.table(letter, runs, [_nan(rec.meta["metrics"]) for rec in found])
        lines += [f"### {title}", "", intro, "", *table, ""]
    return lines


def explain(
    settings: ExplainSettings,
    out,
    *,
    batch_size: int = 24,
    console: Console | None = None,
    warn: Callable[[str], None] = warn_stderr,
) -> engine.Outcome:
    """Run (or resume) the claim explanations in folder ``out`` on the study engine and write
    ``out/claims_explained.md`` (one section, the wall time of every session added up);
    ``Outcome.finished`` is ``(markdown path, the section's lines)``."""
    console = Console(quiet=True) if console is None else console
    started = time.perf_counter()

    def header(on_disk: int, to_run: int) -> str:
        return f"experiments {settings.only} -> {out} ({on_disk} trials on disk, {to_run} to run)"

    def finish(run: StudyRun, outcome: engine.Outcome):
        console.end(len(outcome.computed))
        body = markdown(settings, run, warn=lambda _: None)
        wall = run.add_wall_time(time.perf_counter() - started)
        command = "python sweeps/explain_claims.py" + (" --quick" if settings.quick else "")
        n = len(settings.trials())
        head = [f"## Experiments (generated by `{command}`)", ""]
        head += [f"{n} trials, {wall / 60:.1f} min wall time; means ± the 95% t-interval over seeds.", ""]
        path = run.path / MARKDOWN
        atomic_write_text(path, "\n".join(head + body))
        return path, body

    return engine.run(
        settings,
        out,
        batch_size=batch_size,
        progress=console.progress,
        on_start=console.starter(header),
        finish=finish,
        warn=warn,
    )
