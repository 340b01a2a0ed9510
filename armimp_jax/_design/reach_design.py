"""The design of a movement experiment: where in time the perturbation goes, and the robot's
impedance, counted in reaches (``design_reach``).

A reach's stiffness is hardest to see where it is lowest and the hand fastest (mid-reach): the
paper's perturbation spreads its power evenly over the record, most of it where the arm holds
still. ``Envelope`` reshapes any perturbation family over time (its force RMS over the record and
its peak kept: the same clinical limits), and the robot's designed gains (``controller_design``:
PD's ``kp``, ``kv``; IMBIC's ``k_rd``, ``b_rd``) may be scaled down, letting the arm's own impedance
show, within a limit on the hand's departure from its path. Each candidate is scored on the bound
along the path (``path_bound``): the reaches its worst knot diagonal needs for the precision.
"""

from __future__ import annotations

import dataclasses

import jax
import numpy as np

from .._identification import path as ph
from .._identification import path_bound as pb
from .._model.movement import MinimumJerk
from .._simulate import Trial
from . import controller_design as cd

# Shapes of the perturbation over the reach: (name, weight at rest, weight over the reach's span)
SHAPES = (("uniform", 1.0, 1.0), ("reach", 0.3, 1.0), ("reach-only", 0.05, 1.0))
GAIN_SCALES = (1.0, 0.7, 0.5)
RAMP = 0.05  # [s] the envelope's rise into the reach and fall after it


@dataclasses.dataclass(frozen=True)
class Envelope:
    """``family``'s signal times a weight over time: ``rest`` outside ``[start, end]`` [s], ``reach``
    inside (ramps of ``RAMP``), rescaled per axis to the unshaped draw's RMS and clipped at its peak:
    the same peak, and a force RMS over the record at most the unshaped draw's (the clip takes a few
    percent at ``rest = 0.3``)."""

    family: object
    start: float
    end: float
    rest: float
    reach: float

    def signal(self, key, n_samples: int, period: float):
        raw = np.asarray(self.family.signal(key, n_samples, period))
        t = np.arange(n_samples) * period
        # np.interp holds the end values beyond the knots; a reach starting within RAMP of 0 ramps from 0
        knots = [
            max(self.start - RAMP, 0.0),
            self.start + (RAMP if self.start < RAMP else 0.0),
            self.end,
            self.end + RAMP,
        ]
        w = np.interp(t, knots, [self.rest, self.reach, self.reach, self.rest])
        shaped = raw * w[:, None]
        shaped *= np.sqrt(np.mean(raw**2, axis=0) / np.maximum(np.mean(shaped**2, axis=0), 1e-300))[None, :]
        peak = np.max(np.abs(raw), axis=0)
        return np.clip(shaped, -peak, peak)


@dataclasses.dataclass(frozen=True)
class ReachDesign:
    """``design_reach``'s answer: ``candidates`` (a list of dicts: shape, gain scale, worst reaches
    and the entry setting it, the hand's peak departure from its path [m], whether within the
    limit), ``best`` (the within-limit candidate of fewest reaches), ``paper`` (the uniform shape at
    the trial's gains), ``ratio`` (best's reaches over the paper's), ``precision``."""

    candidates: list
    best: dict
    paper: dict
    ratio: float
    precision: float

    def summary(self) -> str:
        lines = [f"Reaches for +-{self.precision:.0%} at 95% on every knot's diagonals (the bound), per design:"]
        for c in self.candidates:
            flag = "" if c["within"] else "  (departs beyond the limit)"
            lines.append(
                f"  {c['shape']:11s} gains x{c['gain_scale']:.2f}: {c['worst']:7d} reaches ({c['limiting']}), "
                f"hand within {1000 * c['departure']:.1f} mm of its path{flag}"
            )
        lines.append(
            f"best: {self.best['shape']} at gains x{self.best['gain_scale']:.2f}, {self.best['worst']} reaches: "
            f"{self.ratio:.2f} of the paper's perturbation at the trial's gains ({self.paper['worst']})"
        )
        return "\n".join(lines)


def _departure(trial: Trial, f, numerics) -> float:
    """The largest distance [m] of the noise-free hand from its unperturbed path over the draws ``f``."""
    free = ph.deterministic(trial, np.zeros_like(f[0]), numerics)
    moved = [np.asarray(ph.deterministic(trial, fr, numerics) - free)[:, :2] for fr in f]
    return float(max(np.max(np.hypot(m[:, 0], m[:, 1])) for m in moved))


def design_reach(
    trial: Trial,
    family,
    *,
    samples: int,
    precision: float = 0.1,
    shapes=SHAPES,
    gain_scales=GAIN_SCALES,
    peak_departure: float | None = None,
    draws: int = 8,
    key=None,
    numerics=None,
    entries=None,
) -> ReachDesign:
    """Score each shape of ``family`` over the reach and each scale of the robot's designed gains
    on the bound along the path (module docstring); the best within ``peak_departure`` [m].

    Args:
        trial: a moving arm's trial (its path's onset and duration place the reach's span).
        family: the perturbation family (``PaperNoise``, ...), its RMS and peak the clinical limits.
        samples: samples per reach.
        peak_departure: the hand's largest allowed distance [m] from its path in the noise-free
            simulation (``None``: the paper's perturbation's at the trial's gains, times 1.5).
    """
    pb._z(precision, 0.95, "design_reach")
    if ("uniform", 1.0, 1.0) not in [tuple(s) for s in shapes] or 1.0 not in gain_scales:
        raise ValueError(
            "design_reach: the grid must hold the paper's design (shape 'uniform', gain scale 1.0), its reference"
        )
    path = trial.arm.endpoint
    if not isinstance(path, MinimumJerk):
        raise ValueError("design_reach: the trial's arm does not reach (its endpoint is no MinimumJerk path)")
    start, end = float(path.onset), float(path.onset + path.duration)
    key = jax.random.key(0) if key is None else key
    log_gains = cd.initial_log_gains(trial)
    numerics = numerics or pb.IDENTIFY_NUMERICS
    candidates = []
    for name, rest, reach in shapes:
        shape = Envelope(family, start, end, rest, reach)
        f = ph.perturbation_draws(shape, key, draws, samples, float(trial.period))
        for scale in gain_scales:
            t = cd.with_gains(trial, log_gains + np.log(scale)) if scale != 1.0 else trial
            count = pb.path_crlb(t, f, numerics=numerics).reaches_for(precision, entries=entries)
            limiting = max(count, key=count.get)
            candidates.append(
                dict(
                    shape=name,
                    gain_scale=scale,
                    worst=count[limiting],
                    limiting=limiting,
                    departure=_departure(t, f, numerics),
                )
            )
    paper = next(c for c in candidates if c["shape"] == "uniform" and c["gain_scale"] == 1.0)
    limit = 1.5 * paper["departure"] if peak_departure is None else float(peak_departure)
    for c in candidates:
        c["within"] = c["departure"] <= limit
    best = min((c for c in candidates if c["within"]), key=lambda c: c["worst"])  # the paper's is within
    return ReachDesign(candidates, best, paper, best["worst"] / paper["worst"], precision)
