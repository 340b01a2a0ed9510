"""The paper's two experiments as data, per-trial summary metrics, and the claims (a)-(f).

Spec section 12. A *condition* fixes controller, location, friction level, perturbation
level and acquisition; a *trial* is a condition plus a seed. The claims are judged from
numbers by explicit, documented thresholds (``CLAIM_RULES``), never by hand, so a
report can be regenerated from saved results and the rules can be tested on synthetic
numbers.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._metrics import largest_singular_value
from ._presets import arm

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


# --- Claims -----------------------------------------------------------------------------
# Each rule reads condition means of the instant-acquisition trials. "Reproduced" needs
# every part of a claim, "partly" some, "not" none.
CLAIM_RULES = {
    "a": "PD, friction 0: median multiple coherence (x and F_h) >= 0.95, and phi_T <= 10% of mean ||Z_h||",
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


@dataclass
class Claim:
    key: str
    claim: str
    rule: str
    ours: str
    verdict: str  # "reproduced", "partly", "not", or "n/a" (conditions missing)


def _verdict(parts: list[bool]) -> str:
    return "reproduced" if all(parts) else ("partly" if any(parts) else "not")


def evaluate_claims(summary: dict) -> list[Claim]:
    """Judge claims (a)-(f) from condition means.

    ``summary`` maps ``Condition`` -> dict of mean metrics (the keys of ``trial_metrics``).
    Only instant-acquisition conditions are read. A claim whose conditions are missing
    gets verdict ``"n/a"``.
    """
    s = {c: m for c, m in summary.items() if c.acquisition == "instant"}

    def get(exp, loc, fr, pert):
        return s.get(Condition(exp, exp, loc, fr, pert))

    claims = []

    def add(key, ours, parts):
        claims.append(Claim(key, CLAIM_TEXT[key], CLAIM_RULES[key], ours, _verdict(parts) if parts else "n/a"))

    pd0 = [get("pd", 1, 0, p) for p in (1, 2, 3)]
    pd0 = [m for m in pd0 if m]
    if pd0:
        coh = min(min(m["coh_multiple_x_median"], m["coh_multiple_fh_median"]) for m in pd0)
        rel = max(m["rel_error"] for m in pd0)
        add(
            "a",
            f"median multiple coherence >= {coh:.3f}; phi_T = {100 * rel:.1f}% of mean ||Z_h|| (worst level)",
            [coh >= 0.95, rel <= 0.10],
        )
    else:
        add("a", "conditions missing", [])

    pdf = [(fr, p, get("pd", 1, fr, p)) for fr in (1, 2) for p in (1, 2, 3)]
    pdf = [(fr, p, m) for fr, p, m in pdf if m]
    if pdf and pd0:
        coh_low = max(m["coh_multiple_x_min_low"] for _, _, m in pdf)
        base = {p: get("pd", 1, 0, p) for p in (1, 2, 3)}
        ratios = [m["phi_T"] / base[p]["phi_T"] for _, p, m in pdf if base.get(p)]
        phase = min(m["phase_error_deg"] for _, _, m in pdf)
        add(
            "b",
            f"min coherence below 2 Hz <= {coh_low:.2f}; phi_T {min(ratios):.1f}-{max(ratios):.1f}x "
            f"frictionless; phase error >= {phase:.0f} deg",
            [coh_low <= 0.5, min(ratios) >= 5.0, phase >= 20.0],
        )
    else:
        add("b", "conditions missing", [])

    pairs = [(fr, get("pd", 1, fr, 1), get("pd", 1, fr, 3)) for fr in (1, 2)]
    ratios_c = {fr: b["phi_T"] / a["phi_T"] for fr, a, b in pairs if a and b}
    if ratios_c:
        add(
            "c",
            "phi_T(level 3) / phi_T(level 1): " + ", ".join(f"{r:.2f} at friction {fr}" for fr, r in ratios_c.items()),
            [r >= 2 / 3 for r in ratios_c.values()],
        )
    else:
        add("c", "conditions missing", [])

    im = {(loc, fr): get("imbic", loc, fr, 1) for loc in (1, 2, 3, 4) for fr in (0, 1, 2)}
    im = {k: v for k, v in im.items() if v}
    if im:
        worst_min = min(min(m["coh_multiple_x_min_low"], m["coh_multiple_x_min_high"]) for m in im.values())
        worst_med = min(m["coh_multiple_x_median"] for m in im.values())
        parts = [worst_min > 0.9] if worst_min > 0.9 else [False, worst_med > 0.9]
        add("d", f"min multiple coherence {worst_min:.3f}, lowest median {worst_med:.3f}", parts)
    else:
        add("d", "conditions missing", [])

    e_parts, e_text = [], []
    ratios_e = [im[(loc, fr)]["phi_T"] / im[(loc, 0)]["phi_T"] for (loc, fr) in im if fr > 0 and (loc, 0) in im]
    if ratios_e:
        e_parts.append(max(ratios_e) <= 2.0)
        e_text.append(f"IMBIC phi_T {min(ratios_e):.2f}-{max(ratios_e):.2f}x frictionless")
    vs_pd = [
        im[(1, fr)]["phi_T"] / get("pd", 1, fr, 1)["phi_T"] for fr in (1, 2) if (1, fr) in im and get("pd", 1, fr, 1)
    ]
    if vs_pd:
        e_parts.append(max(vs_pd) <= 0.2)
        e_text.append(f"{100 * max(vs_pd):.1f}% of PD's at most")
    add("e", "; ".join(e_text) or "conditions missing", e_parts)

    spreads = []
    for fr in (0, 1, 2):
        vals = [im[(loc, fr)]["phi_T"] for loc in (1, 2, 3, 4) if (loc, fr) in im]
        if len(vals) == 4:
            spreads.append(max(vals) / min(vals))
    if spreads:
        worst = max(spreads)
        add(
            "f",
            f"max/min phi_T over locations <= {worst:.2f}",
            [worst <= 2.0] if worst <= 2.0 else [False, worst <= 4.0],
        )
    else:
        add("f", "conditions missing", [])
    return claims
