"""The paper's two experiments as data, per-trial summary metrics, seed statistics, and the
claims (a)-(f).

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
side of its threshold that the verdict says.

``fit_metrics`` fits ``M, B, K`` to each trial's estimate (``fit_impedance``, uniform
weights) and scores them against the arm's (``true_matrices``); the report tables them.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import jax
import numpy as np

from .._estimation.fit import fit_impedance
from .._estimation.metrics import largest_singular_value
from ..presets import arm
from ..study.stats import CI_LEVEL as CI_LEVEL
from ..study.stats import mean_ci

LOW_BAND_HZ = 2.0  # the paper's "below 1-2 Hz"


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


def trial_metrics(f, Z, est_arrays: dict, location: int) -> dict:
    """Scalar summaries of one estimate: accuracy, phase error, coherence minima per band.

    ``est_arrays`` holds the ``Estimate`` coherence arrays as NumPy (``coh_multiple_x``...).
    """
    f = np.asarray(f)
    zt = np.asarray(arm(location).impedance(f))
    err = zt - Z
    phi_t = float(np.mean(np.asarray(largest_singular_value(err))))
    scale = float(np.mean(np.asarray(largest_singular_value(zt))))
    phase = np.degrees(np.abs(np.angle(Z / zt)))
    low, high = f < LOW_BAND_HZ, f >= LOW_BAND_HZ
    m = dict(
        phi_T=phi_t,
        phi_ij=np.mean(np.abs(err), axis=0).tolist(),
        rel_error=phi_t / scale,
        phase_error_deg=float(np.mean(phase)),
    )
    for name in ("coh_multiple_x", "coh_partial_x", "coh_multiple_fh", "coh_partial_fh"):
        c = np.asarray(est_arrays[name])
        m[f"{name}_min_low"] = float(c[low].min()) if low.any() else float("nan")
        m[f"{name}_min_high"] = float(c[high].min()) if high.any() else float("nan")
        m[f"{name}_median"] = float(np.median(c))
    m["input_coherence_max"] = float(np.max(est_arrays["coh_inputs"]))
    return m


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
    fit = functools.partial(fit_impedance, acquisition=acquisition)
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
    every metric ``m`` of ``trial_metrics``: ``m`` (mean), ``m_sd`` (sample standard
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
# Each rule reads condition means of the instant-acquisition trials. "Reproduced" needs
# every part of a claim, "partly" some, "not" none; for (d) and (f) "partly" is a looser
# second threshold.
CLAIM_RULES = {
    "a": "PD, friction 0: median multiple coherence (x and F_h) >= 0.95, and phi_T <= 10% of mean ‖Z_h‖",
    "b": "PD, friction 1-2: min multiple coherence of x below 2 Hz <= 0.5; phi_T >= 5x the frictionless value; "
    "mean phase error >= 20 deg",
    "c": "PD, friction 1 and 2 each: phi_T at perturbation level 3 >= 2/3 of its value at level 1 "
    "(partly: at one friction level)",
    "d": "IMBIC: min multiple coherence of x over 0-15 Hz > 0.9 at every friction level and location "
    "(partly: median > 0.9)",
    "e": "IMBIC, friction 1-2: phi_T <= 2x the frictionless IMBIC value; and <= 20% of PD's at the same friction "
    "(location 1, perturbation 1)",
    "f": "IMBIC: for each friction level, max/min of phi_T over the four locations <= 2 (partly: <= 4)",
}

CLAIM_TEXT = {
    "a": "PD without friction: coherences ~1, estimate nearly indistinguishable from Z_h",
    "b": "PD with friction: low coherence below 1-2 Hz, estimate far off in magnitude and especially phase",
    "c": "PD with friction: larger perturbations do not noticeably help",
    "d": "IMBIC: multiple coherence > 0.9 over 0-15 Hz at every friction level",
    "e": "IMBIC: phi only slightly above frictionless, far below PD with friction",
    "f": "IMBIC: no noticeable change across the four arm locations",
}

# The conditions each claim reads (to say which all-diverged ones it had to leave out).
CLAIM_READS: dict[str, Callable[[Condition], bool]] = {
    "a": lambda c: c.experiment == "pd" and c.friction == 0,
    "b": lambda c: c.experiment == "pd",
    "c": lambda c: c.experiment == "pd" and c.friction > 0 and c.perturbation in (1, 3),
    "d": lambda c: c.experiment == "imbic",
    "e": lambda c: c.experiment == "imbic" or (c.experiment == "pd" and c.perturbation == 1 and c.friction > 0),
    "f": lambda c: c.experiment == "imbic",
}

_OPS = {">=": np.greater_equal, "<=": np.less_equal, ">": np.greater, "<": np.less}


def _compare(value, op: str, threshold: float) -> bool:
    return bool(np.isfinite(value) and _OPS[op](value, threshold))


@dataclass(frozen=True)
class Part:
    """One threshold comparison of a claim: ``value op threshold``."""

    label: str
    value: float
    op: str
    threshold: float

    @property
    def holds(self) -> bool:
        return _compare(self.value, self.op, self.threshold)


@dataclass(frozen=True)
class Judgement:
    """A claim's quantities on one summary: the text and the threshold comparisons.
    ``tiered``: reproduced when ``parts[0]`` holds, partly when ``parts[1]`` does."""

    ours: str
    parts: tuple[Part, ...]
    tiered: bool = False

    @property
    def verdict(self) -> str:
        ok = [p.holds for p in self.parts]
        if self.tiered:
            return "reproduced" if ok[0] else ("partly" if ok[1] else "not")
        return "reproduced" if all(ok) else ("partly" if any(ok) else "not")

    @property
    def deciding(self) -> tuple[int, ...]:
        """Indices of the parts whose outcome fixes the verdict."""
        if self.tiered and self.parts[0].holds:
            return (0,)
        return tuple(range(len(self.parts)))


Get = Callable[[str, int, int, int], "dict | None"]


def _judge_a(get: Get) -> Judgement | None:
    pd0 = [m for m in (get("pd", 1, 0, p) for p in (1, 2, 3)) if m]
    if not pd0:
        return None
    coh = min(min(m["coh_multiple_x_median"], m["coh_multiple_fh_median"]) for m in pd0)
    rel = max(m["rel_error"] for m in pd0)
    return Judgement(
        f"median multiple coherence >= {coh:.3f}; phi_T = {100 * rel:.1f}% of mean ‖Z_h‖ (worst level)",
        (Part("lowest median multiple coherence", coh, ">=", 0.95), Part("phi_T / mean ‖Z_h‖", rel, "<=", 0.10)),
    )


def _judge_b(get: Get) -> Judgement | None:
    pdf = [(p, m) for fr in (1, 2) for p in (1, 2, 3) if (m := get("pd", 1, fr, p))]
    base = {p: m for p in (1, 2, 3) if (m := get("pd", 1, 0, p))}
    if not pdf or not base:
        return None
    coh_low = max(m["coh_multiple_x_min_low"] for _, m in pdf)
    ratios = [m["phi_T"] / base[p]["phi_T"] for p, m in pdf if p in base]
    phase = min(m["phase_error_deg"] for _, m in pdf)
    parts = [Part("highest min coherence below 2 Hz", coh_low, "<=", 0.5)]
    text = f"min coherence below 2 Hz <= {coh_low:.2f}; "
    if ratios:
        parts.append(Part("smallest phi_T / frictionless", min(ratios), ">=", 5.0))
        text += f"phi_T {min(ratios):.1f}-{max(ratios):.1f}x frictionless; "
    parts.append(Part("smallest phase error [deg]", phase, ">=", 20.0))
    return Judgement(text + f"phase error >= {phase:.0f} deg", tuple(parts))


def _judge_c(get: Get) -> Judgement | None:
    ratios = {fr: b["phi_T"] / a["phi_T"] for fr in (1, 2) if (a := get("pd", 1, fr, 1)) and (b := get("pd", 1, fr, 3))}
    if not ratios:
        return None
    return Judgement(
        "phi_T(level 3) / phi_T(level 1): " + ", ".join(f"{r:.2f} at friction {fr}" for fr, r in ratios.items()),
        tuple(Part(f"phi_T(3) / phi_T(1) at friction {fr}", r, ">=", 2 / 3) for fr, r in ratios.items()),
    )


def _imbic(get: Get) -> dict:
    return {(loc, fr): m for loc in (1, 2, 3, 4) for fr in (0, 1, 2) if (m := get("imbic", loc, fr, 1))}


def _judge_d(get: Get) -> Judgement | None:
    im = _imbic(get)
    if not im:
        return None
    worst_min = min(min(m["coh_multiple_x_min_low"], m["coh_multiple_x_min_high"]) for m in im.values())
    worst_med = min(m["coh_multiple_x_median"] for m in im.values())
    return Judgement(
        f"min multiple coherence {worst_min:.3f}, lowest median {worst_med:.3f}",
        (Part("lowest min multiple coherence", worst_min, ">", 0.9), Part("lowest median", worst_med, ">", 0.9)),
        tiered=True,
    )


def _judge_e(get: Get) -> Judgement | None:
    im = _imbic(get)
    parts, text = [], []
    ratios = [im[(loc, fr)]["phi_T"] / im[(loc, 0)]["phi_T"] for (loc, fr) in im if fr > 0 and (loc, 0) in im]
    if ratios:
        parts.append(Part("largest IMBIC phi_T / frictionless", max(ratios), "<=", 2.0))
        text.append(f"IMBIC phi_T {min(ratios):.2f}-{max(ratios):.2f}x frictionless")
    vs_pd = [im[(1, fr)]["phi_T"] / pd["phi_T"] for fr in (1, 2) if (1, fr) in im and (pd := get("pd", 1, fr, 1))]
    if vs_pd:
        parts.append(Part("largest IMBIC / PD phi_T", max(vs_pd), "<=", 0.2))
        text.append(f"{100 * max(vs_pd):.1f}% of PD's at most")
    return Judgement("; ".join(text), tuple(parts)) if parts else None


def _judge_f(get: Get) -> Judgement | None:
    im = _imbic(get)
    spreads = []
    for fr in (0, 1, 2):
        vals = [im[(loc, fr)]["phi_T"] for loc in (1, 2, 3, 4) if (loc, fr) in im]
        if len(vals) == 4:
            spreads.append(max(vals) / min(vals))
    if not spreads:
        return None
    worst = max(spreads)
    return Judgement(
        f"max/min phi_T over locations <= {worst:.2f}",
        (
            Part("max/min phi_T over locations", worst, "<=", 2.0),
            Part("max/min phi_T over locations", worst, "<=", 4.0),
        ),
        tiered=True,
    )


JUDGES: dict[str, Callable[[Get], Judgement | None]] = dict(
    a=_judge_a, b=_judge_b, c=_judge_c, d=_judge_d, e=_judge_e, f=_judge_f
)


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


def _interval_says(lo: float, hi: float, op: str, threshold: float) -> str:
    a, b = _compare(lo, op, threshold), _compare(hi, op, threshold)
    return "holds" if a and b else ("fails" if not (a or b) and np.isfinite(lo) and np.isfinite(hi) else "straddles")


def _robustness(
    judged: Judgement, parts: list[dict], seed_verdicts: list[str], n_total: int
) -> tuple[str, bool | None]:
    n = len(seed_verdicts)
    skipped = f"; {n_total - n} seed(s) left out (a trial the claim needs diverged)" if n < n_total else ""
    if n < 2:
        return f"{n} seed{'s' if n != 1 else ''}: no interval{skipped}", None
    verdict = judged.verdict
    agree = seed_verdicts.count(verdict)
    others = {v: seed_verdicts.count(v) for v in ("reproduced", "partly", "not") if v != verdict and v in seed_verdicts}
    text = f"{verdict} on {agree}/{n} seeds" + (
        " (" + ", ".join(f"{v} on {k}" for v, k in others.items()) + ")" if others else ""
    )
    bad = []
    for i in judged.deciding:
        p = parts[i]
        want = "holds" if p["holds"] else "fails"
        if p["ci_says"] != want:
            lo, hi = p["ci"]
            bad.append(f"95% CI of {p['label']} [{lo:.3g}, {hi:.3g}] {p['ci_says']} {p['op']} {p['threshold']:.3g}")
    # say what the intervals confirm: that a rule holds, or fails, not merely that they are decisive
    outcomes = {parts[i]["holds"] for i in judged.deciding}
    if bad:
        text += "; " + "; ".join(bad)
    elif outcomes == {True}:
        text += "; every deciding rule also holds on its 95% CI over the seeds"
    elif outcomes == {False}:
        text += "; every deciding rule also fails on its 95% CI over the seeds"
    else:
        n_fail = sum(not parts[i]["holds"] for i in judged.deciding)
        n_hold = len(judged.deciding) - n_fail
        fails, holds = ("fails" if n_fail == 1 else "fail"), ("holds" if n_hold == 1 else "hold")
        text += (
            f"; the 95% CIs over the seeds confirm every deciding rule's outcome: {n_fail} {fails}, {n_hold} {holds}"
        )
    return text + skipped, agree == n and not bad


def evaluate_claims(summary: Mapping, per_seed: Mapping | None = None) -> list[Claim]:
    """Judge claims (a)-(f) on the seed ensemble.

    Args:
        summary: ``Condition`` -> mean metrics (``condition_summary``; the keys of
            ``trial_metrics``). Conditions with ``n == 0`` (every trial diverged) are left
            out, and the claims that read them say so.
        per_seed: ``seed -> {Condition: metrics}`` (``seed_summaries``): each seed is judged
            alone, and each comparison gets a t-interval over the seeds. ``None``: no
            per-seed judgement (robustness ``"no interval"``).

    Only instant-acquisition conditions are read. A claim whose conditions are missing
    gets verdict ``"n/a"``.
    """
    instant = {c: m for c, m in summary.items() if c.acquisition == "instant"}
    dead = sorted(c for c, m in instant.items() if m.get("n", 1) == 0)
    s = {c: m for c, m in instant.items() if m.get("n", 1) != 0}
    seeds = {sd: {c: m for c, m in ms.items() if c.acquisition == "instant"} for sd, ms in (per_seed or {}).items()}
    claims = []
    for key, judge in JUDGES.items():
        reads: set[Condition] = set()

        def get(exp, loc, fr, pert, reads=reads):
            m = s.get(Condition(exp, exp, loc, fr, pert))
            if m is not None:
                reads.add(Condition(exp, exp, loc, fr, pert))
            return m

        judged = judge(get)
        left_out = [c.label for c in dead if CLAIM_READS[key](c)]
        note = f"; left out (every trial diverged): {', '.join(left_out)}" if left_out else ""
        if judged is None:
            claims.append(
                Claim(
                    key,
                    CLAIM_TEXT[key],
                    CLAIM_RULES[key],
                    "conditions missing" + note,
                    "n/a",
                    robustness="n/a",
                    left_out=left_out,
                )
            )
            continue
        verdicts, values = [], []
        for ms in seeds.values():
            if not reads <= ms.keys():
                continue  # a trial this claim needs diverged on this seed
            one = judge(lambda exp, loc, fr, pert, ms=ms: ms.get(Condition(exp, exp, loc, fr, pert)))
            if one is None or [p.label for p in one.parts] != [p.label for p in judged.parts]:
                continue
            verdicts.append(one.verdict)
            values.append([p.value for p in one.parts])
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
        robustness, robust = (
            _robustness(judged, parts, verdicts, len(seeds))
            if per_seed is not None
            else (
                "no per-seed data: no interval",
                None,
            )
        )
        claims.append(
            Claim(
                key,
                CLAIM_TEXT[key],
                CLAIM_RULES[key],
                judged.ours + note,
                judged.verdict,
                robustness=robustness,
                robust=robust,
                seeds=len(verdicts),
                seed_verdicts={v: verdicts.count(v) for v in dict.fromkeys(verdicts)},
                parts=parts,
                left_out=left_out,
            )
        )
    return claims
