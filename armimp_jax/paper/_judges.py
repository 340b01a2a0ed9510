"""The rules that judge the paper's claims (a)-(f) from numbers, and the text that says
what the numbers were.

Each judge reads condition means (or one seed's metrics) through ``get(experiment,
location, friction, perturbation)`` and returns a ``Judgement``: the text of what we
measured (``ours``) and the threshold comparisons (``Part``). The text names each quantity
and gives its value (``short``: the digits of the report's comparison table, a coherence
never rounded up to 1); it states no inequality, because a rounded bound can read true
where the unrounded one is false.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ._text import short

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

_OPS = {">=": np.greater_equal, "<=": np.less_equal, ">": np.greater, "<": np.less}


def compare(value, op: str, threshold: float) -> bool:
    """``value op threshold``; a non-finite value never holds."""
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
        return compare(self.value, self.op, self.threshold)


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
        f"lowest median multiple coherence (x and F_h, over perturbation levels) {short(coh)}; "
        f"phi_T = {100 * rel:.1f}% of mean ‖Z_h‖ at the worst level",
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
    parts = [Part("highest min multiple coherence of x below 2 Hz", coh_low, "<=", 0.5)]
    text = f"highest min multiple coherence of x below 2 Hz {short(coh_low)}; "
    if ratios:
        parts.append(Part("smallest phi_T / frictionless", min(ratios), ">=", 5.0))
        text += f"phi_T {short(min(ratios))}-{short(max(ratios))}x frictionless; "
    parts.append(Part("smallest mean phase error [deg]", phase, ">=", 20.0))
    return Judgement(text + f"smallest mean phase error {short(phase)} deg", tuple(parts))


def _judge_c(get: Get) -> Judgement | None:
    ratios = {fr: b["phi_T"] / a["phi_T"] for fr in (1, 2) if (a := get("pd", 1, fr, 1)) and (b := get("pd", 1, fr, 3))}
    if not ratios:
        return None
    return Judgement(
        "phi_T(level 3) / phi_T(level 1): " + ", ".join(f"{short(r)} at friction {fr}" for fr, r in ratios.items()),
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
        f"over locations and friction levels: lowest min multiple coherence of x {short(worst_min)}, "
        f"lowest median {short(worst_med)}",
        (
            Part("lowest min multiple coherence of x", worst_min, ">", 0.9),
            Part("lowest median multiple coherence of x", worst_med, ">", 0.9),
        ),
        tiered=True,
    )


def _judge_e(get: Get) -> Judgement | None:
    im = _imbic(get)
    parts, text = [], []
    ratios = [im[(loc, fr)]["phi_T"] / im[(loc, 0)]["phi_T"] for (loc, fr) in im if fr > 0 and (loc, 0) in im]
    if ratios:
        parts.append(Part("largest IMBIC phi_T / frictionless", max(ratios), "<=", 2.0))
        text.append(f"IMBIC phi_T {short(min(ratios))}-{short(max(ratios))}x frictionless")
    vs_pd = [im[(1, fr)]["phi_T"] / pd["phi_T"] for fr in (1, 2) if (1, fr) in im and (pd := get("pd", 1, fr, 1))]
    if vs_pd:
        parts.append(Part("largest IMBIC / PD phi_T", max(vs_pd), "<=", 0.2))
        text.append(f"largest IMBIC / PD phi_T {100 * max(vs_pd):.1f}%")
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
        f"max/min phi_T over the four locations, at the worst friction level: {short(worst)}",
        (
            Part("max/min phi_T over locations", worst, "<=", 2.0),
            Part("max/min phi_T over locations", worst, "<=", 4.0),
        ),
        tiered=True,
    )


JUDGES: dict[str, Callable[[Get], Judgement | None]] = dict(
    a=_judge_a, b=_judge_b, c=_judge_c, d=_judge_d, e=_judge_e, f=_judge_f
)
