"""armimp_jax.study.runs.engine: one engine (run folder, lock, resume, batches, progress, finish)
for every study, tested on a toy specification whose batches simulate nothing."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from armimp_jax.study.runs import engine
from armimp_jax.study.runs.results import ResultsError, describe_difference, load_record, stamped
from armimp_jax.study.runs.runfolder import StudyRun


@dataclasses.dataclass(frozen=True)
class Toy:
    """Trials ``(i, seed)``; trial ``i`` has ``sizes[i]`` samples, and trials of one size
    share a batch. Every batch run is logged in ``LOG`` (group purity is checked there)."""

    KIND = "toy"
    FORMAT = 1
    NOUN = "toy run"

    sizes: tuple = (30, 30, 50, 30)
    seeds: int = 2
    scale: float = 1.0

    def validate(self) -> None:
        if not self.scale > 0:
            raise ValueError(f"scale must be > 0, got {self.scale}")

    def run_settings(self) -> dict:
        return stamped(dict(sizes=list(self.sizes), seeds=self.seeds, scale=self.scale))

    def run_extra(self) -> dict:
        return dict(wall_s=0.0)

    describe = staticmethod(describe_difference)

    @classmethod
    def from_saved(cls, saved, *, where):
        return cls(tuple(saved["sizes"]), saved["seeds"], saved["scale"])

    def trials(self):
        return [(i, s) for i in range(len(self.sizes)) for s in range(self.seeds)]

    def trial_record(self, t):
        return f"t{t[0]}-s{t[1]}", stamped(dict(size=self.sizes[t[0]], seed=t[1], scale=self.scale))

    def group(self, t):
        return self.sizes[t[0]]

    def samples(self, t):
        return self.sizes[t[0]]

    def runner(self, context):
        chunk_samples = context.chunk_samples

        def run(batch, progress):
            LOG.append(list(batch))
            n, b = self.samples(batch[0]), len(batch)
            for done in range(chunk_samples, n + chunk_samples, chunk_samples):  # in trial samples, like simulate_batch
                progress(b * min(done, n), b * n, 0.0)
            return [
                (
                    dict(x=np.full(3, self.scale * (10 * i + s))),
                    dict(id=f"t{i}-s{s}", batch_size=None, value=10 * i + s),
                )
                for i, s in batch
            ]

        return run


LOG: list = []


def run(spec, out, **kw):
    outcome = engine.run(spec, out, warn=kw.pop("warn", lambda _: None), chunk_seconds=0.01, **kw)
    return outcome.done, outcome.computed


def test_batches_are_equal_per_group_and_never_mix():
    items = [("a", k) for k in range(5)] + [("b", k) for k in range(3)] + [("a", 5)]
    got = engine.batches(items, lambda t: t[0], 2)
    assert [len(b) for b in got] == [2, 2, 2, 2, 1]  # group a: 6 in 3 batches of 2; group b: 3 as 2 + 1
    assert all(len({t[0] for t in b}) == 1 for b in got)
    assert [len(b) for b in engine.batches(items, lambda t: t[0], 4)] == [3, 3, 3]  # equal, not 4 + 2
    mapped = engine.map_batches(items, lambda t: t[0], 2, lambda b: [f"{g}{k}" for g, k in b])
    assert mapped == [f"{g}{k}" for g, k in items]  # results come back in the items' order


def test_resume_loses_nothing_and_runs_each_trial_once(tmp_path):
    LOG.clear()
    spec = Toy()
    done, first = run(spec, tmp_path, batch_size=3, stop_after_batches=2)  # "interrupted"
    assert done == [] and len(first) == 6  # the six 30-sample trials, as two batches of 3
    assert all(len({spec.group(t) for t in b}) == 1 for b in LOG)  # no batch mixes groups
    warnings = []
    torn = StudyRun.of(spec, tmp_path).record_path(first[0])
    torn.write_bytes(torn.read_bytes()[:100])  # a record cut short is named and recomputed
    done, second = run(spec, tmp_path, batch_size=3, warn=warnings.append)
    assert len(done) == 5 and first[0] in second and not set(first[1:]) & set(second)
    assert len(warnings) == 1 and str(torn) in warnings[0]
    assert sorted(set(first) | set(second)) == sorted(spec.trial_record(t)[0] for t in spec.trials())
    assert all(len({spec.group(t) for t in b}) == 1 for b in LOG)
    done, third = run(spec, tmp_path, batch_size=2)
    assert third == [] and len(done) == 8
    rec = load_record(StudyRun.of(spec, tmp_path).record_path("t2-s1"), settings=spec.trial_record((2, 1))[1])
    assert rec.meta["value"] == 21 and rec.meta["batch_size"] == 2 and rec.meta["batch_wall_s"] >= 0
    assert list(rec.meta) == ["id", "batch_size", "value", "batch_wall_s"]  # a spec's placement is kept
    np.testing.assert_array_equal(rec.arrays["x"], [21.0] * 3)


def test_a_run_with_other_settings_is_refused_and_foreign_records_are_recomputed(tmp_path):
    run(Toy(), tmp_path, batch_size=8)
    other = Toy(scale=2.0)
    with pytest.raises(ResultsError, match=r"holds a toy run with scale=1 \(you asked 2\)"):
        run(other, tmp_path)
    saved = engine.resumed(Toy, tmp_path)
    assert saved == Toy()
    with pytest.raises(ResultsError, match="--resume"):
        engine.resumed(Toy, tmp_path, lambda s: other)
    # records written under other trial settings are not taken for this run's
    (tmp_path / "run.json").unlink()
    warnings = []
    done, computed = run(other, tmp_path, batch_size=8, warn=warnings.append)
    assert done == [] and len(computed) == 8 and len(warnings) == 8
    with pytest.raises(ValueError, match="scale must be > 0"):
        run(Toy(scale=-1.0), tmp_path / "bad")
    assert StudyRun.of(other, tmp_path).add_wall_time(1.5) == 1.5
    assert StudyRun.of(Toy, tmp_path).add_wall_time(2.0) == 3.5


def test_progress_counts_samples_and_trials_and_leaves_compilation_out(tmp_path):
    reports = []
    spec = Toy(sizes=(30, 50), seeds=4)
    run(spec, tmp_path, batch_size=2, progress=reports.append)
    total = 4 * 30 + 4 * 50
    assert all(r["total"] == total and r["trials_total"] == 8 for r in reports)
    done = [r["done"] for r in reports]
    assert done == sorted(done) and done[-1] == total
    assert [r["trials_done"] for r in reports if r["done"] in (60, 120, 220, 320)] == [0, 2, 4, 6]
    # the first chunk of each new shape (30 x 2, then 50 x 2) compiles: no rate from it alone
    assert math.isnan(reports[0]["eta_s"]) and all(r["eta_s"] >= 0 for r in reports[1:])
    assert reports[-1]["eta_s"] == 0.0


def test_a_run_made_by_another_version_is_refused_in_one_line_naming_both(tmp_path):
    """Saved results are stamped with the version that made them: a folder of 0.4 is not
    resumed by this version (its numbers might differ), and the refusal says so."""
    import json

    from armimp_jax.study.runs.results import settings_key

    run(Toy(), tmp_path, batch_size=8)
    path = tmp_path / "run.json"
    saved = json.loads(path.read_text())
    saved["settings"]["armimp_jax"] = "0.4.0"
    saved["key"] = settings_key(saved["settings"])  # as 0.4 wrote it: not an edited file
    path.write_text(json.dumps(saved))
    with pytest.raises(
        ResultsError, match=r"made by armimp_jax 0\.4\.0, and this is \S+: results of two versions"
    ) as e:
        run(Toy(), tmp_path)
    assert "\n" not in str(e.value)
