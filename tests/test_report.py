"""The words of the reproduction report and the claims' texts: each number says what it is,
a coherence is never rounded up to 1, no rounded bound reads true where the value fails it,
and the report names the acquisition and what its wall time covers. Synthetic results, no
simulation."""

import dataclasses
import re

import pytest

from armimp_jax.paper import report
from armimp_jax.paper._text import short
from armimp_jax.paper.claims import (
    Condition,
    condition_summary,
    evaluate_claims,
    paper_conditions,
    seed_summaries,
    trial_id,
)


@pytest.mark.parametrize(
    "x, spec, text",
    [
        (0.9996, ".3f", "0.9996"),  # the newcomer's "median multiple coherence >= 1.000"
        (0.99996, ".3f", "0.99996"),
        (0.9996, ".3g", "0.9996"),
        (0.996, ".2f", "0.996"),
        (-0.9996, ".3f", "-0.9996"),
        (1.0, ".3f", "1.000"),  # exactly 1 stays 1
        (0.872, ".3f", "0.872"),
        (0.9994, ".3f", "0.999"),  # rounds down: already honest
        (18.7, ".3g", "18.7"),
        (2.0004, ".3g", "2"),  # above 1: the ordinary format
    ],
)
def test_short_never_rounds_a_value_under_one_up_to_one(x, spec, text):
    assert short(x, spec) == text


def _metrics(cond: Condition, seed: int) -> dict:
    """Paper-like metrics: a frictionless PD whose median coherence is 0.9996 (to 3 decimals
    1.000), friction that hurts PD and barely IMBIC."""
    phi = 200.0 + 5 * seed if cond.friction == 0 or cond.experiment == "imbic" else 3000.0 + 10 * seed
    phi += 10 * cond.location if cond.experiment == "imbic" else 0
    coh = 0.9996 if cond.friction == 0 else (0.3 if cond.experiment == "pd" else 0.95)
    return dict(
        phi_T=phi,
        phi_ij=[[phi / 2, phi / 4], [phi / 4, phi / 2]],
        rel_error=phi / 8000.0,
        phase_error_deg=18.7 if cond.friction else 2.0,
        coh_multiple_x_min_low=coh,
        coh_multiple_x_min_high=coh,
        coh_multiple_x_median=coh,
        coh_multiple_fh_median=coh,
        coh_multiple_fh_min_low=coh,
        coh_multiple_fh_min_high=coh,
        coh_partial_x_min_low=coh,
        coh_partial_x_min_high=coh,
        input_coherence_max=0.1,
    )


@pytest.fixture(scope="module")
def results():
    """``aggregate``-shaped results of two seeds over the paper's instant conditions."""
    metas = [
        dict(
            id=trial_id(c, s),
            condition=dataclasses.asdict(c),
            seed=s,
            diverged=False,
            perturbation_attempt=0,
            input_coherence_max=0.1,
            metrics=_metrics(c, s),
        )
        for c in paper_conditions(ablation=False)
        for s in (0, 1)
    ]
    summary = condition_summary(metas)
    return dict(
        complete=True,
        settings=dict(seconds=50.0, nperseg=8192, noverlap=6144, mhat=0.25, seeds=2, fmax=15.0),
        key="k",
        versions=dict(armimp_jax="test"),
        trials_expected=len(metas),
        diverged=[],
        trials=metas,
        conditions=[dict(condition=dataclasses.asdict(c), **m) for c, m in summary.items()],
        claims=[dataclasses.asdict(c) for c in evaluate_claims(summary, seed_summaries(metas))],
        wall_s=12.34,
    )


def test_claim_texts_name_their_quantities_and_state_no_rounded_bound(results):
    claims = {c["key"]: c for c in results["claims"]}
    lead = "lowest median multiple coherence (x and F_h, over perturbation levels) 0.9996;"
    assert claims["a"]["ours"].startswith(lead)
    assert "smallest mean phase error 18.7 deg" in claims["b"]["ours"]  # not "phase error >= 19 deg"
    for c in claims.values():
        assert not re.search(r"<=|>=|at most", c["ours"]), c["ours"]
        assert "1.000" not in c["robustness"] and " 1]" not in c["robustness"], c["robustness"]


def test_the_report_says_what_each_number_is(results, tmp_path):
    md = report.write_report(results, tmp_path, []).read_text()
    assert md == report.report_text(results, tmp_path, [])
    assert "1.000" not in md and "| 0.9996 |" in md  # the comparison table, on the means
    assert "| 1 | 0 | 1 | 0.9996 ± 0.000 |" in md  # the coherence table of PD, location 1, friction 0
    assert "Conditions are named `experiment-L<location>-F<friction level>-P<perturbation level>`" in md
    assert "| phi_T / mean ‖Z_h‖ | mean abs. phase error [deg] |" in md
    assert "between the two perturbation axes over 0-15 Hz" in md
    # the recorded wall time, with what it covers; none recorded says so
    assert "- wall time: 12.3 s, as recorded in `run.json` (`wall_s`): simulating the trials, aggregating" in md
    assert "- wall time: not recorded" in report.report_text(results | dict(wall_s=None), tmp_path, [])
    # results without fits (an older armimp_jax): the report says so
    assert "hold no fitted matrices" in md
