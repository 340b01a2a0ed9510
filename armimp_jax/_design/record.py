"""How long to record: ``record_for``, the record a planned experiment needs for a precision, as
three answers side by side (``RecordLength``), all in one convention: ``+- precision`` at
``level`` (default 95%), the relative half-width of the level's interval on each entry.

- **the Cramér-Rao bound** (``crlb``): the least record any unbiased estimator needs, of the
  loop without its joints' Coulomb friction (near-linear loops only): a floor, not a plan;
- **through the friction** (``predict_se``): ``identify``'s own standard errors, simulated
  through the friction-aware closed loop with the trial's noise: the record to plan on;
- **a design's** (``design``'s answer, when one is given): its worst arm at its own signal and
  controller, through the friction where it was calibrated (or designed by Monte Carlo).

Each comes from the standard errors at the record given, carried by the one-over-square-root
law (``precision.record_seconds``, checked in ``tests/test_bound.py`` and
``tests/test_identify.py``); ``check=True`` predicts again at the answer's length (the
perturbation repeated), which costs that record's simulations.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from .._checks import check_choice, check_int, deprecated, require_x64
from .._identification import indirect
from .._identification import layout as lay
from .._identification.bound import NEAR_LINEAR, crlb, has_friction, is_near_linear
from .._identification.identify import MIN_SAMPLES
from .._identification.precision import check_precision, quantile, record_seconds
from .._identification.predict import STATISTICS, check_signal, predict_se
from .._simulate import Trial
from .bound_design import BoundDesign
from .criterion import default_targets, relative_se
from .monte_carlo_design import Design

CHECK_LIMIT_S = 3600.0  # [s] check=True predicts again at the answer only up to an hour
ROWS = ("bound", "predicted", "design")


@dataclasses.dataclass(frozen=True)
class RecordLength:
    """``record_for``'s answer: seconds of recording per entry for ``+- precision`` at ``level``,
    three ways (``None`` where not asked; NaN where no number holds, ``notes`` saying why).

    Attributes:
        entries: the entries' labels (e.g. ``"arm.stiffness[0,0]"``).
        precision: ``{entry: relative half-width}`` asked (0.1: +-10%); level: its confidence.
        seconds: the record [s] the standard errors were predicted at (``f``'s length).
        bound: ``{entry: seconds}`` by the Cramér-Rao bound: a floor, the loop without friction.
        predicted: ``{entry: seconds}`` by ``predict_se``, through the friction: plan on these.
        design: ``{entry: seconds}`` by a design's answer (its worst arm, its own signal).
        design_basis: what the design's rest on: ``"predict_se"`` or ``"bound"``.
        statistic, draws: ``predict_se``'s (``identify``'s statistic; the draws behind it).
        friction: whether the trial's robot has Coulomb friction (which the bound leaves out).
        check: with ``check=True``, ``{entry: relative half-width at level}`` that ``predict_se``
            gives at ``record_s`` itself (``None`` unless asked, or past ``CHECK_LIMIT_S``).
        notes: why a number is missing (no bound, a check not run).
    """

    entries: tuple
    precision: dict
    level: float
    seconds: float
    bound: dict
    predicted: dict
    design: dict | None
    design_basis: str
    statistic: str
    draws: int
    friction: bool
    period: float
    check: dict | None = None
    notes: tuple = ()

    @property
    def record_s(self) -> float:
        """The record to plan on [s]: the longest ``predicted``, rounded up to a control period."""
        longest = self.longest("predicted")
        if not math.isfinite(longest):
            return float("nan")
        return max(int(math.ceil(longest / self.period - 1e-9)), MIN_SAMPLES) * self.period

    def longest(self, row: str) -> float:
        """The longest seconds of ``row`` (``"bound"``, ``"predicted"``, ``"design"``) over the
        entries; NaN where the row is missing or an entry has no number."""
        check_choice("row", row, ROWS)
        values = list((getattr(self, row) or {}).values())
        return float(max(values)) if values and all(math.isfinite(v) for v in values) else float("nan")

    def summary(self) -> str:
        """The three answers side by side in minutes, per entry and the longest, then which to
        plan on and why they differ."""
        return "\n".join(record_lines(self))

    def __getitem__(self, key):
        """The dictionary ``record_for(target=...)`` returned (deprecated)."""
        deprecated(
            f"record_for(...)[{key!r}]",
            "read RecordLength's attributes (record_s, predicted, statistic, check)",
        )
        if key in self.predicted:
            return self.predicted[key]
        z = quantile(self.level)
        legacy = dict(
            record_s=self.record_s,
            statistic=self.statistic,
            check=None if self.check is None else {e: w / z for e, w in self.check.items()},
        )
        return legacy[key]


def _headers(friction: bool, basis: str) -> dict:
    through = "predict_se, through the friction" if friction else "predict_se (identify)"
    return {"bound": "bound: floor, no friction", "predicted": through, "design": f"design: worst arm ({basis})"}


def _minutes(seconds: float) -> str:
    return "-" if not math.isfinite(seconds) else f"{seconds / 60:.3g} min"


def _percent(width: float) -> str:
    return f"+-{100 * width:.3g}%"


def _precision_words(precision: dict, level: float) -> str:
    low, high = min(precision.values()), max(precision.values())
    what = _percent(low) if low == high else f"{_percent(low)} to {_percent(high)} (per entry)"
    return f"{what} at {level:.0%} (the relative half-width of the {level:.0%} interval)"


def record_lines(r: RecordLength) -> list[str]:
    """``RecordLength.summary``'s lines."""
    rows = [row for row in ROWS if getattr(r, row) is not None]
    heads = _headers(r.friction, r.design_basis)
    width = max(len(e) for e in (*r.entries, "longest"))
    cols = [max(len(heads[row]), 10) for row in rows]
    lines = [
        f"How long to record for {_precision_words(r.precision, r.level)}, from standard errors at a "
        f"{r.seconds:g} s record:",
        "  ".join([" " * width] + [heads[row].rjust(c) for row, c in zip(rows, cols, strict=True)]),
    ]
    for e in (*r.entries, "longest"):
        cells = [_minutes(r.longest(row) if e == "longest" else getattr(r, row)[e]) for row in rows]
        lines.append("  ".join([e.ljust(width)] + [v.rjust(c) for v, c in zip(cells, cols, strict=True)]))
    return lines + why_lines(r)


def why_lines(r: RecordLength) -> list[str]:
    """Which answer to plan on, and why the others differ from it."""
    plan, bound, design = r.longest("predicted"), r.longest("bound"), r.longest("design")
    noise = math.sqrt(2.0 / r.draws)  # an SE over R draws is good to 1/sqrt(2R); minutes go as its square
    if math.isfinite(plan):
        lines = [
            f"plan on {plan / 60:.3g} min ({r.record_s:g} s): identify's own standard errors (predict_se, the "
            f"{r.statistic} statistic, {r.draws} draws: about +-{noise:.0%} in minutes from the draws alone)"
        ]
    else:
        lines = ["no record to plan on: predict_se gave no finite standard error here (the notes say why)"]
    if math.isfinite(bound) and math.isfinite(plan):
        loop = "the loop without its Coulomb friction" if r.friction else "this loop"
        cause = "the joints' Coulomb friction, which the bound leaves out" if r.friction else "identify's statistic"
        lines.append(
            f"the bound's {bound / 60:.3g} min is a floor no unbiased estimator beats, of {loop}; predict_se "
            f"needs {plan / bound:.2g} times it, the cost of {cause}"
        )
    if r.design is not None:
        lines.append(
            f"the design's {design / 60:.3g} min is its own answer at its own signal and controller over its arms "
            f"(the worst; {'through the friction' if r.design_basis == 'predict_se' else 'the bound: calibrate it'}): "
            "the record if you run the designed perturbation instead of this one"
        )
    if r.check is not None:
        worst = max(r.check, key=lambda e: r.check[e] / r.precision[e])
        lines.append(
            f"checked at {r.record_s:g} s: predict_se gives {_percent(r.check[worst])} on {worst} (asked "
            f"{_percent(r.precision[worst])}; the draws' noise is about +-{noise / 2:.0%} in SE)"
        )
    return lines + [f"note: {n}" for n in r.notes]


def record_for(
    trial: Trial,
    f,
    *,
    free,
    precision=0.1,
    level: float = 0.95,
    entries=None,
    design: BoundDesign | Design | None = None,
    statistic: str = "auto",
    draws: int = 64,
    key=None,
    check: bool = False,
    target: dict | None = None,
) -> RecordLength:
    """How long to record with the perturbation ``f`` ``(N, 2)`` [N] (repeated, or cut) for
    ``+- precision`` at ``level`` on each entry: the bound's, ``predict_se``'s through the
    friction (plan on it) and, given a ``design``, the design's, side by side (module docstring).

    Args:
        trial: the planned experiment, noise included (as ``predict_se``).
        f: the perturbation; its length is the record the standard errors are predicted at.
        free: the parameters ``identify`` will estimate (names as ``identify``).
        precision: the relative half-width of the ``level`` interval (0.1: +-10%), for every
            entry; or ``{entry: precision}`` (then ``entries`` is its keys).
        level: the intervals' confidence (default 0.95).
        entries: labels (e.g. ``"arm.stiffness[1,1]"``); default every free entry but the
            off-diagonals of the matrices (a design's default targets).
        design: a ``design`` answer (``BoundDesign`` or ``Design``) whose own record is set beside:
            per entry the worst of its arms, at its signal; ``entries`` must be among its targets.
        statistic: as ``identify``'s (``"auto"``: the efficient statistic where the loop is
            near-linear under ``f``, else Welch's); draws, key: ``predict_se``'s.
        check: predict again at the answer's length (up to ``CHECK_LIMIT_S``), at the cost of
            that record's simulations: about ``record_s / seconds`` times the first prediction.
        target: deprecated: ``{entry: relative SE}``, the same goal as ``precision={entry:
            quantile(level) * SE}`` (1.96 SE at 95%).

    Returns a ``RecordLength``. One-line ``ValueError`` before any simulation for a bad input.
    """
    require_x64("record_for")
    layout, precision = _check_record(trial, f, free, precision, level, entries, draws, check, target, statistic)
    f = check_signal(trial, f, "record_for")
    design_rel = None if design is None else _design_relative(design, tuple(precision), "record_for")
    notes = []
    bound_rel, near = _bound_relative(trial, f, free, layout, tuple(precision), notes)
    statistic = _statistic(trial, f, layout, statistic, near)
    pred = predict_se(trial, f, free=free, statistic=statistic, draws=draws, key=key)
    if bool(pred.diverged):
        notes.append(
            "a simulated draw of predict_se diverged, so its prediction is unsound: a smaller perturbation, or "
            "a controller that holds this arm stably"
        )
    predicted_rel = relative_se(pred, trial, free=free, targets=tuple(precision))
    seconds = f.shape[0] * trial.period

    def carried(rel, at):
        return {e: record_seconds(at, rel[e], precision[e], level=level, where="record_for") for e in precision}

    out = RecordLength(
        entries=tuple(precision),
        precision=precision,
        level=level,
        seconds=seconds,
        bound=carried(bound_rel, seconds),
        predicted=carried(predicted_rel, seconds),
        design=None if design_rel is None else _worst_arm(carried, design_rel),
        design_basis="" if design_rel is None else design_rel[2],
        statistic=statistic,
        draws=draws,
        friction=has_friction(trial),
        period=trial.period,
        notes=tuple(notes),
    )
    return _checked(out, trial, f, free, key) if check else out


def _checked(out: RecordLength, trial, f, free, key) -> RecordLength:
    """``out`` with ``predict_se`` run again at its record (the perturbation repeated, or cut):
    each entry's half-width there, or a note past ``CHECK_LIMIT_S``."""
    if out.record_s > CHECK_LIMIT_S:  # the check would simulate every draw over that record
        return dataclasses.replace(
            out, notes=(*out.notes, f"no check past {CHECK_LIMIT_S:g} s: it simulates the record")
        )
    longer = np.resize(f, (int(round(out.record_s / out.period)), 2))
    pred = predict_se(trial, longer, free=free, statistic=out.statistic, draws=out.draws, key=key)
    again = relative_se(pred, trial, free=free, targets=out.entries)
    return dataclasses.replace(out, check={e: quantile(out.level) * again[e] for e in out.entries})


def _check_record(trial, f, free, precision, level, entries, draws, check, target, statistic="auto"):
    """``(layout, {entry: precision})``: every input checked, one line each, before any simulation."""
    if not isinstance(trial, Trial):
        raise ValueError(f"record_for: trial must be a Trial (from make_trial), got {type(trial).__name__}")
    if not trial.noisy:
        raise ValueError("record_for: the trial has no noise (ideal sensors, no voluntary force): any record is exact")
    layout = lay.make_layout(free, friction=trial.friction, where="record_for")
    labels = layout.labels()
    check_int("draws", draws, minimum=8)
    check_choice("statistic", statistic, STATISTICS)
    if not isinstance(check, bool):
        raise ValueError(f"record_for: check must be True or False, got {check!r}")
    if target is not None:
        deprecated("record_for(target={entry: relative SE})", "pass precision={entry: 1.96 * SE} (+-X at 95%)")
        if not isinstance(target, dict) or not target or entries is not None or isinstance(precision, dict):
            raise ValueError(
                f"record_for: target (deprecated) must map entry labels to relative SEs alone, got {target!r}"
            )
        bad = {e: v for e, v in target.items() if not (isinstance(v, (int, float)) and 0 < v < 1)}
        if bad:
            raise ValueError(f"record_for: target relative SEs must lie in (0, 1), got {bad}")
        check_precision(0.1, level, where="record_for")
        precision = {e: quantile(level) * float(v) for e, v in target.items()}
    if isinstance(precision, dict):
        if entries is not None:
            raise ValueError("record_for: give entries or a precision per entry ({entry: precision}), not both")
        entries = list(precision)
    entries = [labels[i] for i in default_targets(layout)] if entries is None else list(entries)
    unknown = [e for e in entries if e not in labels]
    if not entries or unknown:
        raise ValueError(
            f"record_for: unknown entry {unknown[:1] or entries!r}; the free parameters' entries are "
            f"{', '.join(labels)}"
        )
    widths = precision if isinstance(precision, dict) else dict.fromkeys(entries, precision)
    for w in widths.values():
        check_precision(w, level, where="record_for")
    values = np.asarray(lay.natural_with_jacobian(layout, lay.pack(layout, trial), trial)[0])
    zero = [e for e in entries if values[labels.index(e)] == 0]
    if zero:
        raise ValueError(
            f"record_for: {zero[0]} is 0 in the trial, so a relative precision means nothing there; "
            "leave it out of entries"
        )
    return layout, {e: float(widths[e]) for e in entries}


def _bound_relative(trial, f, free, layout, entries, notes) -> tuple[dict, bool | None]:
    """``({entry: relative SE bound, NaN where none holds}, near-linear or None if unchecked)``: the
    bound's check (one noise-free simulation) also decides ``identify``'s statistic."""
    nan = dict.fromkeys(entries, float("nan"))
    if not all(n in lay.ARM_PARAMETERS for n in layout.names):
        notes.append("no bound: it covers the arm's matrices, and the free parameters hold others")
        return nan, None
    b = crlb(trial, f, free=free)
    if not b.near_linear:
        notes.append(f"no bound: {b.message}")
        return nan, (None if np.isnan(b.nonlinearity).all() else bool(np.max(b.nonlinearity[:2]) <= NEAR_LINEAR))
    return b.relative(entries), True


def _statistic(trial, f, layout, statistic: str, near) -> str:
    """The statistic ``identify`` would use (as ``predict_se``'s ``"auto"``), decided once:
    Welch's where no arm matrix is free or the loop is not near-linear."""
    if indirect.arm_layout(layout) is None:
        return "welch"
    if statistic != "auto":
        return statistic
    near = is_near_linear(trial, f) if near is None else near
    return "efficient" if near else "welch"


def _design_relative(design, entries, where: str) -> tuple[list, float, str]:
    """``(per arm {entry: relative SE}, the design's record [s], "predict_se" or "bound")``: what
    a design's own answer rests on at its signal (``predict_se``'s through the friction where it
    was calibrated or designed by Monte Carlo, else the bound's); one-line errors."""
    if not isinstance(design, (BoundDesign, Design)):
        raise ValueError(f"{where}: design must be aj.design's answer, got {type(design).__name__}")
    missing = [e for e in entries if e not in design.targets]
    if missing:
        raise ValueError(f"{where}: the design predicted its targets {list(design.targets)}, not {missing[0]}")
    seconds = np.shape(design.signal)[0] * design.trials[0].period
    if isinstance(design, Design):
        per_arm = [relative_se(p, t, free=design.free, targets=entries) for p, t in zip(design.after, design.trials)]
        return per_arm, seconds, "predict_se"
    per_arm = [b.relative(entries) for b in design.bounds]
    if design.friction_ratio is None:
        return per_arm, seconds, "bound"
    ratios = [dict(zip(design.targets, row, strict=True)) for row in np.asarray(design.friction_ratio)]
    return [{e: rel[e] * q[e] for e in entries} for rel, q in zip(per_arm, ratios, strict=True)], seconds, "predict_se"


def _worst_arm(carried, design_rel) -> dict:
    """Per entry the longest record over the design's arms."""
    per_arm, seconds, _ = design_rel
    each = [carried(rel, seconds) for rel in per_arm]
    return {e: max(arm[e] for arm in each) for e in each[0]}


def design_lines(design, precision: float, *, level: float = 0.95, labels=None, written_s=None) -> list[str]:
    """A design's answer per arm in ``record_for``'s convention and labels, from the numbers it
    holds (no new simulation): the bound's minutes (a ``BoundDesign``'s) and ``predict_se``'s
    through the friction (calibrated, or Monte Carlo), the worst arm, which to plan on, and the
    record written (``written_s`` [s], when given)."""
    check_precision(precision, level, where="design_lines")
    seconds = np.shape(design.signal)[0] * design.trials[0].period
    labels = labels or [f"arm {k + 1}" for k in range(len(design.trials))]
    entries = tuple(design.targets)
    bound = [b.relative(entries) for b in design.bounds] if isinstance(design, BoundDesign) else None
    predicted = None
    if isinstance(design, Design) or design.friction_ratio is not None:
        predicted = _design_relative(design, entries, "design_lines")[0]
    columns = {
        row: [max(record_seconds(seconds, r[e], precision, level=level) for e in entries) for r in rels]
        for row, rels in (("bound", bound), ("predicted", predicted))
        if rels is not None
    }
    friction = any(has_friction(t) for t in design.trials)
    heads = _headers(friction, "")
    width = max(len(s) for s in (*labels, "worst arm"))
    cols = {row: len(heads[row]) for row in columns}
    lines = [
        f"How long to record for {_percent(precision)} at {level:.0%} (the relative half-width of the {level:.0%} "
        f"interval) on every target ({', '.join(entries)}), from standard errors at the {seconds:g} s signal:",
        "  ".join([" " * width] + [heads[row].rjust(c) for row, c in cols.items()]),
    ]
    for k, label in enumerate((*labels, "worst arm")):
        cells = [_minutes(max(v) if k == len(labels) else v[k]) for v in columns.values()]
        lines.append("  ".join([label.ljust(width)] + [v.rjust(c) for v, c in zip(cells, cols.values(), strict=True)]))
    plan = "predicted" if "predicted" in columns else "bound"
    why = {
        "predicted": "predict_se's worst arm: identify's own standard errors",
        "bound": "the bound's worst arm" + (": it leaves the friction out, calibrate to see it" if friction else ""),
    }[plan]
    lines.append(f"plan on {max(columns[plan]) / 60:.3g} min ({why})")
    if written_s is not None:
        lines.append(f"the record written: {written_s:g} s ({written_s / 60:.3g} min)")
    return lines
