"""The paper's two experiments as data, seed statistics, the fitted ``M, B, K``, and the
claims (a)-(f) judged over the seeds.

Spec section 12. A *condition* fixes controller, location, friction level, perturbation
level and acquisition; a *trial* is a condition plus a seed. The claims are judged from
numbers by explicit, documented thresholds (``CLAIM_RULES``), never by hand, so a
report can be regenerated from saved results and the rules can be tested on synthetic
numbers.

The paper ran one trial per condition; we run several seeds. ``condition_summary``
averages each metric over the seeds whose trial did not diverge (with the sample standard
deviation and the 95% t-interval of the mean); a diverged trial is counted and left out.
``evaluate_claims`` judges each claim on those means, then again on every seed alone,
and gives each threshold comparison the 95% t-interval of its quantity over the seeds:
a verdict is *robust* when every seed gives it and every relevant interval lies on the
side of its threshold that the verdict says. The rules themselves (``CLAIM_RULES``,
``JUDGES``) and the text of what each claim measured live in ``_judges``; this module
holds the conditions, the statistics and the judging over seeds.

Each trial's scores are ``study.sweep.metrics.trial_metrics``'s. ``fit_metrics`` fits ``M, B, K``
to each trial's estimate (``fit_impedance``, uniform weights) and scores them against the
arm's (``true_matrices``); the report tables them.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import jax
import numpy as np

from .._estimation.fit import fit_impedance
from .._estimation.welch import Welch
from ..presets import arm
from ..presets._tables import FRICTION_LEVELS
from ..study.schema.points import Point
from ..study.sweep.stats import CI_LEVEL as CI_LEVEL
from ..study.sweep.stats import mean_ci
from ._judges import CLAIM_RULES as CLAIM_RULES
from ._judges import CLAIM_TEXT as CLAIM_TEXT
from ._judges import JUDGES as JUDGES
from ._judges import Judgement as Judgement
from ._judges import Part as Part
from ._judges import compare
from ._text import interval


@dataclass(frozen=True, order=True)
class Condition:
    """One cell of an experiment (hashable, sortable)."""

    experiment: str  # "pd" (paper section II) or "imbic" (section III)
    controller: str
    location: int
    friction: int
    perturbation: int
    acquisition: str = "instant"

    @property
    def label(self) -> str:
        acq = "" if self.acquisition == "instant" else "-mean"
        return f"{self.experiment}-L{self.location}-F{self.friction}-P{self.perturbation}{acq}"

    def point(self, *, mhat: float = 0.25, seconds: float = 50.0, welch: Welch | None = None) -> Point:
        """The condition as the one trial description, a sweep point (``study.Point``): the
        paper's controller (IMBIC's ``mhat`` [kg] times the identity),
        arm location, friction level (its LuGre parameters), perturbation level and
        acquisition, a record of ``seconds`` [s] and the ``welch`` settings (default
        Table 4's). Its ``trial`` is ``presets.trial``'s trial, leaf for leaf."""
        w = Welch() if welch is None else welch
        return Point.parse(
            dict(
                controller=self.controller,
                arm=self.location,
                perturbation_level=self.perturbation,
                acquisition=self.acquisition,
                seconds=seconds,
                nperseg=w.nperseg,
                noverlap=w.noverlap,
                fmax=w.fmax,
                **(dict(mhat=mhat) if self.controller == "imbic" else {}),
                **friction_point(self.friction),
            )
        )


def friction_point(level: int) -> dict:
    """The point settings of the paper's friction level 0-2 (Table 1): the Coulomb torque, the
    stiction as its ratio (1.5 at levels 1 and 2), the bristle, viscous and Stribeck parameters."""
    p = FRICTION_LEVELS[level]
    ratio = p.tau_s / p.tau_c if p.tau_c > 0 else 1.5
    return dict(tau_c=p.tau_c, stiction_ratio=ratio, sigma0=p.sigma0, sigma1=p.sigma1, sigma2=p.sigma2, v_s=p.v_s)


def paper_conditions(
    *, ablation: bool = True, locations=(1, 2, 3, 4), frictions=(0, 1, 2), perturbations=(1, 2, 3)
) -> list[Condition]:
    """Section II (PD, location 1, friction x perturbation) and section III (IMBIC,
    locations x friction, perturbation 1); with ``ablation`` the same again with the
    ``"interval_mean"`` acquisition."""
    acqs = ("instant", "interval_mean") if ablation else ("instant",)
    out = []
    for acq in acqs:
        out += [Condition("pd", "pd", 1, f, p, acq) for f in frictions for p in perturbations]
        out += [Condition("imbic", "imbic", loc, f, 1, acq) for loc in locations for f in frictions]
    return out


def trial_id(cond: Condition, seed: int) -> str:
    return f"{cond.label}-S{seed}"


# --- Fitted M, B, K ----------------------------------------------------------------------
FIT_MATRICES = (("M", "mass"), ("B", "damping"), ("K", "stiffness"))  # symbol, ImpedanceFit field


def true_matrices(location: int) -> dict:
    """The arm's ``M`` [kg], ``B`` [N s/m], ``K`` [N/m] at ``location`` as nested lists."""
    a = arm(location)
    return dict(M=np.asarray(a.mass).tolist(), B=np.asarray(a.damping).tolist(), K=np.asarray(a.stiffness).tolist())


def fit_metrics(f, Z, locations, *, acquisition: str = "instant") -> list[dict]:
    """``M, B, K`` fitted to each estimate of a batch (``fit_impedance``, uniform weights,
    the model of the trials' ``acquisition``: the sampled-data relation of instant samples).

    ``f`` ``(F,)`` [Hz], ``Z`` ``(T, F, 2, 2)`` [N/m], ``locations`` ``(T,)``. Per trial:
    ``fit_M``, ``fit_B``, ``fit_K`` ``(2, 2)``; ``fit_M_rel_error`` (and B, K): the relative
    error ``||fit - true||_F / ||true||_F``; ``fit_vaf``: the fit's overall VAF [%]. A trial
    with a non-finite ``Z`` (diverged) gets NaN.
    """
    Z = np.asarray(Z)
    if Z.shape[0] == 0:
        return []
    finite = np.isfinite(Z).all(axis=(1, 2, 3))
    # every option named: the reproduction's numbers must not move with the library's defaults
    # (its SEs are not used here; "residual" needs no error model, which a bare Z lacks)
    fit = functools.partial(fit_impedance, weights=None, acquisition=acquisition, se="residual")
    fits = jax.vmap(fit, in_axes=(0, None))(np.where(finite[:, None, None, None], Z, 1.0), np.asarray(f))
    out = []
    for i, loc in enumerate(locations):
        truth = true_matrices(int(loc))
        m = {}
        for sym, field_name in FIT_MATRICES:
            fitted = np.asarray(getattr(fits, field_name)[i]) if finite[i] else np.full((2, 2), np.nan)
            true = np.asarray(truth[sym])
            m[f"fit_{sym}"] = fitted.tolist()
            m[f"fit_{sym}_rel_error"] = float(np.linalg.norm(fitted - true) / np.linalg.norm(true))
        m["fit_vaf"] = float(fits.vaf_overall[i]) if finite[i] else float("nan")
        out.append(m)
    return out


# --- Seed statistics ----------------------------------------------------------------------
# CI_LEVEL and mean_ci are the study layer's (one level and one interval for every study)


def _plain(x):
    if x is None:
        return None
    x = np.asarray(x, dtype=float)
    return float(x) if x.ndim == 0 else x.tolist()


def condition_summary(metas: list[dict]) -> dict:
    """``Condition -> stats`` over the trials of each condition that did not diverge.

    ``metas`` are trial records (``condition``, ``seed``, ``diverged``, ``metrics``). For
    every metric ``m`` of ``study.sweep.metrics.trial_metrics``: ``m`` (mean), ``m_sd`` (sample standard
    deviation), ``m_ci`` (half-width of the 95% t-interval of the mean; ``None`` with fewer
    than two trials); and ``n`` (trials averaged), ``trials``, ``diverged`` (count),
    ``seeds`` and ``diverged_seeds``. A condition whose every trial diverged has ``n = 0``
    and NaN metrics.
    """
    by_cond: dict[Condition, list] = {}
    for m in metas:
        by_cond.setdefault(Condition(**m["condition"]), []).append(m)
    out = {}
    for cond, group in sorted(by_cond.items()):
        good = [g for g in group if not g["diverged"]]
        agg: dict = {}
        for k in group[0]["metrics"]:
            st = mean_ci([g["metrics"][k] for g in good] or np.empty((0,) + np.shape(group[0]["metrics"][k])))
            agg[k], agg[k + "_sd"], agg[k + "_ci"] = _plain(st.mean), _plain(st.sd), _plain(st.half)
        agg |= dict(
            n=len(good),
            trials=len(group),
            diverged=len(group) - len(good),
            seeds=sorted(g["seed"] for g in good),
            diverged_seeds=sorted(g["seed"] for g in group if g["diverged"]),
        )
        out[cond] = agg
    return out


def seed_summaries(metas: list[dict]) -> dict[int, dict[Condition, dict]]:
    """``seed -> {Condition: metrics}`` of the trials that did not diverge (each seed alone)."""
    out: dict[int, dict] = {}
    for m in metas:
        if not m["diverged"]:
            out.setdefault(m["seed"], {})[Condition(**m["condition"])] = m["metrics"]
    return dict(sorted(out.items()))


# --- Claims -----------------------------------------------------------------------------
# The conditions each claim reads (to say which all-diverged ones it had to leave out).
CLAIM_READS: dict[str, Callable[[Condition], bool]] = {
    "a": lambda c: c.experiment == "pd" and c.friction == 0,
    "b": lambda c: c.experiment == "pd",
    "c": lambda c: c.experiment == "pd" and c.friction > 0 and c.perturbation in (1, 3),
    "d": lambda c: c.experiment == "imbic",
    "e": lambda c: c.experiment == "imbic" or (c.experiment == "pd" and c.perturbation == 1 and c.friction > 0),
    "f": lambda c: c.experiment == "imbic",
}


@dataclass
class Claim:
    """A claim judged on the seed ensemble.

    ``verdict`` comes from the condition means; ``seed_verdicts`` counts the verdict of
    each seed judged alone (``seeds`` of them: those with every condition the claim read);
    ``parts`` lists each threshold comparison with its value on the means, its 95%
    t-interval over the seeds (``ci``, ``None`` under two seeds) and what the interval
    says (``"holds"``, ``"fails"`` or ``"straddles"``); ``robust`` is ``None`` under two
    seeds; ``left_out`` names conditions the claim reads whose every trial diverged.
    """

    key: str
    claim: str
    rule: str
    ours: str
    verdict: str  # "reproduced", "partly", "not", or "n/a" (conditions missing)
    robustness: str = "no interval"
    robust: bool | None = None
    seeds: int = 0
    seed_verdicts: dict = field(default_factory=dict)
    parts: list = field(default_factory=list)
    left_out: list = field(default_factory=list)


# --- judging: on the means, on each seed, and the intervals between ------------------------


def _instant(summary: Mapping) -> tuple[dict, list[Condition]]:
    """The instant-acquisition conditions of ``summary`` with numbers, and (sorted) those
    whose every trial diverged (``n == 0``)."""
    instant = {c: m for c, m in summary.items() if c.acquisition == "instant"}
    dead = sorted(c for c, m in instant.items() if m.get("n", 1) == 0)
    return {c: m for c, m in instant.items() if m.get("n", 1) != 0}, dead


def _judge_means(judge, means: Mapping) -> tuple[Judgement | None, set[Condition]]:
    """``judge`` on the condition means, and the conditions it read."""
    reads: set[Condition] = set()

    def get(exp, loc, fr, pert):
        cond = Condition(exp, exp, loc, fr, pert)
        m = means.get(cond)
        if m is not None:
            reads.add(cond)
        return m

    return judge(get), reads


def _judge_seeds(judge, judged: Judgement, reads: set, seeds: Mapping) -> tuple[list[str], list[list[float]]]:
    """Each seed judged alone: its verdict and its parts' values, for the seeds that hold
    every condition the means read and give the same comparisons."""
    verdicts, values = [], []
    for ms in seeds.values():
        if not reads <= ms.keys():
            continue  # a trial this claim needs diverged on this seed
        one = judge(lambda exp, loc, fr, pert, ms=ms: ms.get(Condition(exp, exp, loc, fr, pert)))
        if one is None or [p.label for p in one.parts] != [p.label for p in judged.parts]:
            continue
        verdicts.append(one.verdict)
        values.append([p.value for p in one.parts])
    return verdicts, values


def _interval_says(lo: float, hi: float, op: str, threshold: float) -> str:
    a, b = compare(lo, op, threshold), compare(hi, op, threshold)
    return "holds" if a and b else ("fails" if not (a or b) and np.isfinite(lo) and np.isfinite(hi) else "straddles")


def _part_records(judged: Judgement, values: list[list[float]]) -> list[dict]:
    """Each comparison as a record: its value on the means, the seeds' values (finite ones),
    their 95% t-interval (``None`` under two) and what that interval says."""
    parts = []
    for i, p in enumerate(judged.parts):
        col = np.array([v[i] for v in values], dtype=float)
        col = col[np.isfinite(col)]
        st = mean_ci(col)
        ci = None if st.half is None else [float(st.mean - st.half), float(st.mean + st.half)]
        parts.append(
            dict(
                label=p.label,
                op=p.op,
                threshold=p.threshold,
                value=float(p.value),
                holds=p.holds,
                seed_values=col.tolist(),
                ci=ci,
                ci_says=None if ci is None else _interval_says(*ci, p.op, p.threshold),
            )
        )
    return parts


# --- robustness: what the seeds and the intervals say ---------------------------------------


def _agreement(verdict: str, seed_verdicts: list[str]) -> str:
    """``"partly on 2/3 seeds (not on 1)"``: how many seeds alone give the verdict."""
    n, agree = len(seed_verdicts), seed_verdicts.count(verdict)
    others = {v: seed_verdicts.count(v) for v in ("reproduced", "partly", "not") if v != verdict and v in seed_verdicts}
    return f"{verdict} on {agree}/{n} seeds" + (
        " (" + ", ".join(f"{v} on {k}" for v, k in others.items()) + ")" if others else ""
    )


def _contradicting(judged: Judgement, parts: list[dict]) -> list[str]:
    """The deciding comparisons whose interval does not lie on the side its mean gives."""
    bad = []
    for i in judged.deciding:
        p = parts[i]
        if p["ci_says"] != ("holds" if p["holds"] else "fails"):
            says = f"{p['ci_says']} {p['op']} {p['threshold']:.3g}"
            bad.append(f"95% CI of {p['label']} {interval(*p['ci'])} {says}")
    return bad


def _confirmed(judged: Judgement, parts: list[dict]) -> str:
    """What the intervals confirm when they all agree with the means: that the deciding
    rules hold, or fail, not merely that they are decisive."""
    outcomes = [parts[i]["holds"] for i in judged.deciding]
    if all(outcomes):
        return "every deciding rule also holds on its 95% CI over the seeds"
    if not any(outcomes):
        return "every deciding rule also fails on its 95% CI over the seeds"
    n_fail = outcomes.count(False)
    n_hold = len(outcomes) - n_fail
    fails, holds = ("fails" if n_fail == 1 else "fail"), ("holds" if n_hold == 1 else "hold")
    return f"the 95% CIs over the seeds confirm every deciding rule's outcome: {n_fail} {fails}, {n_hold} {holds}"


def _robustness(
    judged: Judgement, parts: list[dict], seed_verdicts: list[str], n_total: int
) -> tuple[str, bool | None]:
    """The robustness text and flag: robust when every seed gives the verdict and every
    deciding interval lies on its mean's side of the threshold; ``None`` under two seeds."""
    n = len(seed_verdicts)
    skipped = f"; {n_total - n} seed(s) left out (a trial the claim needs diverged)" if n < n_total else ""
    if n < 2:
        return f"{n} seed{'s' if n != 1 else ''}: no interval{skipped}", None
    bad = _contradicting(judged, parts)
    text = _agreement(judged.verdict, seed_verdicts) + "; " + ("; ".join(bad) if bad else _confirmed(judged, parts))
    return text + skipped, seed_verdicts.count(judged.verdict) == n and not bad


# --- assembly -------------------------------------------------------------------------------


def _left_out_note(left_out: list[str]) -> str:
    return f"; left out (every trial diverged): {', '.join(left_out)}" if left_out else ""


def _unjudged(key: str, left_out: list[str]) -> Claim:
    """A claim none of whose conditions has numbers."""
    ours = "conditions missing" + _left_out_note(left_out)
    return Claim(key, CLAIM_TEXT[key], CLAIM_RULES[key], ours, "n/a", robustness="n/a", left_out=left_out)


def _judged(key: str, judged: Judgement, parts: list[dict], verdicts: list[str], robustness, left_out) -> Claim:
    """A claim judged on the means, with its per-seed record and robustness."""
    text, robust = robustness
    return Claim(
        key,
        CLAIM_TEXT[key],
        CLAIM_RULES[key],
        judged.ours + _left_out_note(left_out),
        judged.verdict,
        robustness=text,
        robust=robust,
        seeds=len(verdicts),
        seed_verdicts={v: verdicts.count(v) for v in dict.fromkeys(verdicts)},
        parts=parts,
        left_out=left_out,
    )


def evaluate_claims(summary: Mapping, per_seed: Mapping | None = None) -> list[Claim]:
    """Judge claims (a)-(f) on the seed ensemble.

    Args:
        summary: ``Condition`` -> mean metrics (``condition_summary``; the keys of
            ``study.sweep.metrics.trial_metrics``). Conditions with ``n == 0`` (every trial diverged) are left
            out, and the claims that read them say so.
        per_seed: ``seed -> {Condition: metrics}`` (``seed_summaries``): each seed is judged
            alone, and each comparison gets a t-interval over the seeds. ``None``: no
            per-seed judgement (robustness ``"no per-seed data: no interval"``).

    Only instant-acquisition conditions are read. A claim whose conditions are missing
    gets verdict ``"n/a"``.
    """
    means, dead = _instant(summary)
    seeds = {sd: {c: m for c, m in ms.items() if c.acquisition == "instant"} for sd, ms in (per_seed or {}).items()}
    claims = []
    for key, judge in JUDGES.items():
        left_out = [c.label for c in dead if CLAIM_READS[key](c)]
        judged, reads = _judge_means(judge, means)
        if judged is None:
            claims.append(_unjudged(key, left_out))
            continue
        verdicts, values = _judge_seeds(judge, judged, reads, seeds)
        parts = _part_records(judged, values)
        robustness = (
            _robustness(judged, parts, verdicts, len(seeds))
            if per_seed is not None
            else ("no per-seed data: no interval", None)
        )
        claims.append(_judged(key, judged, parts, verdicts, robustness, left_out))
    return claims
