"""Issue 62's two counts in reaches, from the model route's Monte Carlo records (``movement_model``'s
run folders): ``reaches_for``'s prediction on the bound against the reaches the spread needs on
the mid-reach ``K`` diagonals (``+-precision`` at 95%), and the designed experiment's worst knot
against the paper's. Each count comes with a bootstrap interval over the ensembles; the bound is
pooled over several sets of perturbation draws (its own draws' noise reported)."""

from __future__ import annotations

import dataclasses
import glob
import json
import pathlib

import numpy as np

from armimp_bench import movement_model as mm
from armimp_bench.movement import measured
from armimp_bench.movement_model import needed
from armimp_jax._identification import path_bound as pb

MID = "arm.stiffness@t=0.8"  # the base reach's mid-reach knot (onset 0.4 s, 0.8 s long)


def load_rows(folders) -> list[dict]:
    """The converged ensembles' records (``ensemble_row``'s) of every run folder."""
    rows = []
    for folder in folders:
        for path in sorted(glob.glob(str(pathlib.Path(folder) / "trials" / "*.npz"))):
            rows.append(json.loads(str(np.load(path)["__record__"]))["meta"])
    return [r for r in rows if r["converged"]]


def pooled_bound(case: str, seeds, draws: int, precision: float) -> dict:
    """``reaches_for`` on the bound whose information is averaged over ``seeds`` (``draws`` draws
    each), and each set's own counts (the draws' noise)."""
    truth, _, _ = mm.case_trials(case)
    sets = [pb.path_crlb(truth, mm.bound_draws(seed=s, draws=draws, case=case)) for s in seeds]
    info = np.mean([b.information for b in sets], axis=0)
    cov = pb.inverse(info, sets[0].labels, "pooled_bound")
    pooled = dataclasses.replace(
        sets[0], information=info, covariance=cov, se=np.sqrt(np.diag(cov)), draws=draws * len(seeds)
    )
    return dict(pooled=pooled.reaches_for(precision), each=[b.reaches_for(precision) for b in sets])


def check(paper_folders, designed_folders, *, seeds=(10_000, 20_000), draws=32, precision=0.1, boots=4000) -> dict:
    """The two counts with 90% bootstrap intervals (``boots`` resamples of the ensembles)."""
    rng = np.random.default_rng(0)
    out = dict(measured=measured(), precision=precision, bound_draws=draws * len(seeds))
    fits = {}
    for case, folders in (("pd", paper_folders), ("pd-designed", designed_folders)):
        rows = load_rows(folders)
        e = np.array([r["estimate"] for r in rows])
        reps = np.array([r.get("repetitions", 40) for r in rows], float)
        true = mm.true_values(case)
        labels = rows[0]["labels"]
        draws_of = [rng.integers(0, len(rows), len(rows)) for _ in range(boots)]
        fits[case] = dict(
            labels=labels,
            need=needed(e, true, reps, precision),
            boots=np.array([needed(e[i], true, reps[i], precision) for i in draws_of]),
            ensembles=len(rows),
        )
    bound = pooled_bound("pd", seeds, draws, precision)
    paper = fits["pd"]
    out["reaches_for"] = []
    for lab in (f"{MID}[0,0]", f"{MID}[1,1]"):
        i = paper["labels"].index(lab)
        predicted = bound["pooled"][lab]
        ratio = predicted / paper["boots"][:, i]
        out["reaches_for"].append(
            dict(
                entry=lab,
                predicted=predicted,
                predicted_each_set=[b[lab] for b in bound["each"]],
                needed=float(paper["need"][i]),
                needed_90=np.percentile(paper["boots"][:, i], [5, 95]).tolist(),
                ratio=float(predicted / paper["need"][i]),
                ratio_90=np.percentile(ratio, [5, 95]).tolist(),
                ensembles=paper["ensembles"],
            )
        )
    out["design"] = _design_ratio(fits["pd"], fits["pd-designed"])
    return out


def _design_ratio(paper: dict, designed: dict) -> dict:
    """The designed experiment's worst knot diagonal over the paper's, in reaches the spread needs."""

    def diag(labels):
        return [i for i, lab in enumerate(labels) if lab.startswith("arm.") and lab.endswith(("[0,0]", "[1,1]"))]

    a, b = diag(designed["labels"]), diag(paper["labels"])
    n = min(len(paper["boots"]), len(designed["boots"]))
    boots = designed["boots"][:n, a].max(axis=1) / paper["boots"][:n, b].max(axis=1)
    worst_designed, worst_paper = float(designed["need"][a].max()), float(paper["need"][b].max())
    return dict(
        designed=worst_designed,
        paper=worst_paper,
        ratio=worst_designed / worst_paper,
        ratio_90=np.percentile(boots, [5, 95]).tolist(),
        p_at_most_half=float(np.mean(boots <= 0.5)),
        ensembles=[designed["ensembles"], paper["ensembles"]],
    )
