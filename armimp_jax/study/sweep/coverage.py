"""Repeated recordings of a case, each identified: the studies of ``identify``'s interval
coverage, its efficiency against the Cramér-Rao bound and the classical route beside it
(``sweeps/bench_identify_coverage.py``, ``bench_identify_efficiency.py``,
``identify_study.py``, ``bench_design_bound.py``), as one specification of the study engine.

- ``Recordings``: a study's cases (each a truth and a perturbation, made by the study) times
  recording seeds; a trial is ``(case, seed)``, its record the row ``one(truth, f, seed)``
  gives (``identify_row``: ``identify``'s values and SEs, and the classical fit's, of one
  recording under new noise). ``engine.run`` resumes a study where it stopped, and more
  seeds or cases extend it (they are not among its settings).
- ``rows``: the rows of every case, in seed order, from the run's checked records.
- ``noise``: the noise these studies meet (force noise 0.05 N, 2^18-count encoders, the
  person's force below 2 Hz); ``spread_and_hits``: the estimates' spread and which 95%
  intervals held the truth; ``coverage_summary``: the coverage study's per-case summary.
"""

from __future__ import annotations

import functools
import re
from collections.abc import Callable, Sequence

import jax
import numpy as np

from ..._identification.bound import crlb
from ..._identification.identify import identify
from ..._identification.indirect import IDENTIFY_NUMERICS
from ..._identification.predict import predict_se
from ..._model.sensors import Sensors
from ..._model.voluntary import VoluntaryForce
from ..._simulate import simulate
from ..runs import engine
from ..runs.console import Console
from ..runs.results import describe_difference, stamped
from ..runs.runfolder import StudyRun, warn_stderr

ARM = ("arm.mass", "arm.damping", "arm.stiffness")
Z95 = 1.959963984540054  # the two-sided 95% normal quantile


def noise(voluntary: float = 0.3) -> dict:
    """``make_trial``'s noise in these studies: force noise 0.05 N, 2^18-count encoders, and the
    person's own force, ``voluntary`` N RMS below 2 Hz."""
    return dict(sensors=Sensors(force_noise=0.05, encoder_counts=2**18), voluntary=VoluntaryForce(voluntary, 2.0))


@functools.cache
def _simulate():
    return jax.jit(simulate, static_argnames="numerics")  # compiled once (a plain call traces anew)


def record(truth, f, key: int):
    """One recording of ``truth`` under ``f`` with its noise drawn from ``key`` (an int)."""
    return _simulate()(truth, f, key=jax.random.key(key), numerics=IDENTIFY_NUMERICS)


def identify_row(truth, f, seed: int, *, free, draws: int, statistic: str = "auto", offset: int = 10_000) -> dict:
    """``identify`` of ``free`` (started at the truth: the intervals are what is measured) and the
    classical fit of one recording of ``truth`` under ``f`` (noise key ``offset + seed``;
    identify's key ``seed``), as plain lists: a record's row."""
    rec = record(truth, f, offset + seed)
    if bool(rec.diverged):
        return dict(seed=seed, diverged=True)
    res = identify(truth, f, rec.x, rec.fh, free=free, statistic=statistic, key=jax.random.key(seed), draws=draws)
    out = dict(
        seed=seed,
        diverged=False,
        converged=res.converged,
        reliable=res.intervals_reliable,
        **{k: getattr(res, k) for k in ("not_told", "statistic", "iterations", "time_s")},
        values={n: np.asarray(v).tolist() for n, v in res.values.items()},
        se={n: np.asarray(v).tolist() for n, v in res.se.items()},
    )
    c = res.classical
    if c is not None:
        out["classical"] = {n: np.asarray(getattr(c, n.split(".")[1])).tolist() for n in ARM}
        out["classical_half_width"] = {}
        for n in ARM:
            low, high = c.interval(n.split(".")[1])
            out["classical_half_width"][n] = (0.5 * (np.asarray(high) - np.asarray(low))).tolist()
    return out


def spread_and_hits(rows, name: str, true):
    """Over ``rows`` of fits: the estimates ``e`` and SEs ``s`` of parameter ``name`` (stacked
    over rows), the estimates' spread (SD, ``ddof=1``), and whether each 95% interval
    ``e +- Z95 s`` held the ``true`` value."""
    e = np.array([r["values"][name] for r in rows])
    s = np.array([r["se"][name] for r in rows])
    return e, s, e.std(axis=0, ddof=1), np.abs(e - true) <= Z95 * s


def truth_of(truth, names) -> dict:
    """``{name: value}`` of the trial's parameters ``names`` (``"arm.mass"``, ``"friction.tau_c"``)."""
    return {n: np.asarray(getattr(getattr(truth, n.split(".")[0]), n.split(".")[1])) for n in names}


class Recordings:
    """A study of repeated recordings: ``cases`` (names) times ``seeds``, on the study engine.

    Args:
        study: the study's name (its run folder refuses another's).
        settings: every value that changes a row apart from the case and the seed (JSON-able).
        cases: the case names, in run order.
        seeds: the recording seeds of every case.
        make: ``make(case) -> (truth, f)``, made once per case and run.
        one: ``one(truth, f, case, seed) -> row`` (JSON-able; ``diverged`` among its keys).
        report: ``report(case, row) -> str`` printed after each sound row (``None``: quiet).
    """

    KIND = "recordings"
    FORMAT = 1
    NOUN = "study of recordings"

    def __init__(
        self,
        study: str,
        settings: dict,
        cases: Sequence[str],
        seeds: Sequence[int],
        make: Callable,
        one: Callable,
        report: Callable | None = None,
    ):
        self.study, self.settings, self.cases, self.seeds = study, dict(settings), list(cases), list(seeds)
        self.make, self.one, self.report = make, one, report

    def validate(self) -> None:
        if not self.cases or not self.seeds:
            raise ValueError(f"{self.study}: no cases or no seeds")

    def run_settings(self) -> dict:
        return stamped(dict(study=self.study, settings=self.settings))

    def run_extra(self) -> dict:
        return {}

    describe = staticmethod(describe_difference)

    def trials(self) -> list[tuple[str, int]]:
        return [(c, s) for c in self.cases for s in self.seeds]

    def trial_record(self, trial) -> tuple[str, dict]:
        case, seed = trial
        return f"{re.sub(r'[^A-Za-z0-9.=-]+', '_', case)}-s{seed}", self.run_settings() | dict(case=case, seed=seed)

    def group(self, trial) -> str:
        return trial[0]

    def samples(self, trial) -> int:
        return 1

    def runner(self, context: engine.Context) -> engine.BatchRunner:
        made: dict = {}

        def run(batch, progress):
            out = []
            for case, seed in batch:
                if case not in made:
                    made.clear()  # one case's truth at a time
                    made[case] = self.make(case)
                row = self.one(*made[case], case, seed)
                if self.report is not None and not row.get("diverged"):
                    print(self.report(case, row), flush=True)
                out.append(({}, row))
            return out

        return run


def rows(spec: Recordings, run, *, warn: Callable[[str], None] = warn_stderr) -> dict[str, list[dict]]:
    """``{case: rows}`` of every recording with a valid record in ``run`` (a ``StudyRun`` or a
    folder), in seed order."""
    records, _ = engine.records(spec, run, warn=warn)
    out: dict[str, list] = {c: [] for c in spec.cases}
    for (case, _seed), rec in records.items():
        out[case].append(rec.meta)
    return {c: sorted(r, key=lambda row: row["seed"]) for c, r in out.items()}


def run_recordings(spec: Recordings, out, *, console: Console | None = None, finish=None) -> engine.Outcome:
    """Run (or resume) ``spec`` in ``out`` on the study engine, one recording per batch (each
    saved as it finishes); ``finish(run, rows)`` (``rows``' answer) runs with the folder locked
    and gives ``Outcome.finished``."""
    console = Console(quiet=True) if console is None else console

    def header(on_disk: int, to_run: int) -> str:
        size = f"{len(spec.cases)} case(s) x {len(spec.seeds)} seed(s)"
        return f"{spec.study}: {size} -> {out} ({on_disk} on disk, {to_run} to run)"

    def done(run: StudyRun, outcome: engine.Outcome):
        console.end(len(outcome.computed))
        return None if finish is None else finish(run, rows(spec, run, warn=lambda _: None))

    return engine.run(spec, out, batch_size=1, on_start=console.starter(header), finish=done, interruptible=True)


def coverage_summary(rows_, truth, f, free, *, draws: int) -> dict:
    """Per parameter of ``free``: the share of 95% intervals holding the truth, the spread
    over the mean SE, the mean error over the spread, ``predict_se`` over the spread, the
    spread over the bound (where the loop has one), and the classical route's coverage and
    bias; pooled, the coverage of every entry (identify's, and the classical route's of the
    arm). A fit that did not converge says so and prints no interval: counted, never scored."""
    ok = [r for r in rows_ if not r["diverged"] and r["converged"]]
    true = truth_of(truth, free)
    pred = predict_se(truth, f, free=free, draws=draws)
    arm_free = tuple(n for n in free if n in ARM)
    bound = crlb(truth, f, free=arm_free) if arm_free else None
    bound = bound if bound is not None and bound.near_linear else None
    out = dict(
        seeds=len(rows_),
        recordings=sum(not r["diverged"] for r in rows_),
        diverged=sum(bool(r["diverged"]) for r in rows_),
        converged=len(ok),
        parameters={},
    )
    hits_all, hits_cls = [], []
    for n in free:
        e, s, spread, hit = spread_and_hits(ok, n, true[n])
        hits_all.append(hit.reshape(len(ok), -1))
        row = dict(
            coverage=hit.mean(axis=0).ravel().tolist(),
            spread_over_se=(spread / s.mean(axis=0)).ravel().tolist(),
            mean_error_over_spread=((e.mean(axis=0) - true[n]) / spread).ravel().tolist(),
            predicted_over_spread=(np.asarray(pred.se[n]) / spread).ravel().tolist(),
        )
        if bound is not None and n in bound.se:
            row["spread_over_bound"] = (spread / np.asarray(bound.se[n])).ravel().tolist()
        if n in ARM and all("classical" in r for r in ok):
            c = np.array([r["classical"][n] for r in ok])
            w = np.array([r["classical_half_width"][n] for r in ok])
            chit = np.abs(c - true[n]) <= w
            hits_cls.append(chit.reshape(len(ok), -1))
            row["classical_coverage"] = chit.mean(axis=0).ravel().tolist()
            row["classical_mean_error_over_spread"] = (
                ((c.mean(axis=0) - true[n]) / c.std(axis=0, ddof=1)).ravel().tolist()
            )
        out["parameters"][n] = row
    out["coverage_all"] = float(np.concatenate(hits_all, axis=1).mean())
    out["classical_coverage_arm"] = float(np.concatenate(hits_cls, axis=1).mean()) if hits_cls else None
    out["mean_time_s"] = float(np.mean([r["time_s"] for r in ok]))
    return out


def coverage_table(cases: dict, *, seeds: int, seconds: float, peak: float, acquisition: str) -> str:
    """The coverage study's table: per case and parameter the coverage per entry, spread / SE,
    predicted / spread, spread / bound and the classical route's coverage."""
    lines = [
        f"\ncoverage of 95% intervals, {seeds} seeds, {seconds:g} s records, peak {peak:g} N, {acquisition}",
        f"{'case':<14}{'parameter':<18}{'coverage (per entry)':<28}{'spread/SE':<22}{'pred/spread':<22}"
        f"{'spread/bound':<22}classical",
    ]

    def cells(values):
        return " ".join(f"{v:.2f}" for v in values)

    for name, case in cases.items():
        s = case["summary"]
        for n, r in s["parameters"].items():
            lines.append(
                f"{name:<14}{n:<18}{cells(r['coverage']):<28}{cells(r['spread_over_se']):<22}"
                f"{cells(r['predicted_over_spread']):<22}{cells(r.get('spread_over_bound', [])):<22}"
                f"{cells(r.get('classical_coverage', []))}"
            )
        cls_all = s["classical_coverage_arm"]
        lines.append(
            f"{'':<14}{'all':<18}{s['coverage_all']:.3f}  (classical, arm: "
            f"{'-' if cls_all is None else format(cls_all, '.3f')}); converged {s['converged']}/{s['recordings']}, "
            f"{s['mean_time_s']:.1f} s per identify"
        )
    return "\n".join(lines)
