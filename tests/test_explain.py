"""armimp_jax.paper.explain: the claim explanations as a specification of the study engine; a
run is the paper's trial through its point, and a second call reuses every record."""

import numpy as np
import pytest

import armimp_jax as aj
from armimp_jax import paper
from armimp_jax.paper import explain
from armimp_jax.paper._experiments import SIGMA1_LOW, Experiments, Run
from armimp_jax.study.schema.points import Point


def _leaves_equal(a, b):
    import jax

    la, ta = jax.tree.flatten(a)
    lb, tb = jax.tree.flatten(b)
    return ta == tb and all(np.array_equal(np.asarray(x), np.asarray(y)) for x, y in zip(la, lb, strict=True))


@pytest.mark.parametrize(
    "run, expected",
    [
        (Run("pd", 1, 0, 6.0, level=2), lambda: paper.trial("pd", 2, 1)),
        (Run("imbic", 3, 0, 6.0, level=1, mhat=0.5), lambda: paper.trial("imbic", 1, 3, mhat=0.5 * np.eye(2))),
        (
            Run("imbic", 2, 0, 6.0, level=0, accel="position", acquisition="interval_mean"),
            lambda: paper.trial("imbic", 0, 2, accel_estimate="position", acquisition="interval_mean"),
        ),
        (
            Run("pd", 1, 0, 6.0, tau_c=2.0, sigma1=SIGMA1_LOW),
            lambda: aj.make_trial(
                aj.PD(), arm=paper.arm(1), friction=aj.LuGre(tau_c=2.0, tau_s=3.0, sigma1=SIGMA1_LOW)
            ),
        ),
    ],
)
def test_a_run_is_the_paper_trial_through_its_point(run, expected):
    assert _leaves_equal(Point.parse(run.point(1024)).trial, expected())


def test_every_experiment_lists_runs_with_segments_for_each_length():
    for letter in Experiments.LETTERS:
        runs, segments = Experiments(explain.QUICK).runs(letter)
        assert runs and all(r.seconds in segments for r in runs), letter


def test_the_study_writes_its_tables_and_reuses_its_records(tmp_path):
    settings = explain.ExplainSettings(quick=True, only="C")
    first = explain.explain(settings, tmp_path, batch_size=24)
    path, lines = first.finished
    assert len(first.computed) == len(settings.trials()) == 20 and first.done == []
    text = path.read_text()
    assert "### C. Claim (c)" in text and "| 1 (level 1) |" in text and "| 4 (level 2) |" in text
    second = explain.explain(settings, tmp_path, batch_size=24)
    assert second.computed == [] and len(second.done) == 20
    assert second.finished[1] == lines  # the same tables, read from the records
    with pytest.raises(ValueError, match="holds a claims study with only=C"):
        explain.explain(explain.ExplainSettings(quick=True, only="D"), tmp_path)
