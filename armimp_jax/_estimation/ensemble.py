"""An ensemble: ``R`` repetitions of one reach, each with its own perturbation and noise
(docs/movement.md). ``Ensemble`` holds what was recorded, simulated (``simulate_ensemble``) or a
lab's own (arrays, or recordings read by ``load_recording``), and checks that its repetitions
are of one reach: the same length and, within ``PATH_TOLERANCE``, the same path. NumPy.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np

from .._model.timing import CONTROL_PERIOD

# A repetition whose hand strays further than this from the others' median path (RMS over the
# record) [m] is of another reach: a lab's reaches to one target stay within millimetres of it.
PATH_TOLERANCE = 0.02


def _repetitions(name: str, value, where: str) -> np.ndarray:
    """``value`` as a ``(R, N, 2)`` float64 array: an array, or a sequence of ``(N, 2)`` ones of one length."""
    if isinstance(value, np.ndarray) or not isinstance(value, Sequence):
        arr = np.asarray(value, dtype=np.float64)
    else:
        parts = [np.asarray(v, dtype=np.float64) for v in value]
        lengths = [p.shape[0] if p.ndim == 2 else -1 for p in parts]
        for r, (p, n) in enumerate(zip(parts, lengths)):
            if p.ndim != 2 or p.shape[1] != 2:
                raise ValueError(f"{where}: {name} of repetition {r} must have shape (N, 2), got {p.shape}")
            if n != lengths[0]:
                raise ValueError(
                    f"{where}: repetition {r} holds {n} samples and repetition 0 {lengths[0]}: every repetition must "
                    "span the same samples (cut each to one window around the reach, aligned on its onset)"
                )
        arr = np.stack(parts) if parts else np.zeros((0, 0, 2))
    if arr.ndim != 3 or arr.shape[2] != 2:
        raise ValueError(f"{where}: {name} must have shape (R, N, 2): repetitions, samples, axes; got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        r, k = np.argwhere(~np.isfinite(arr))[0][:2]
        raise ValueError(f"{where}: {name} of repetition {r} is not finite at sample {k}")
    return arr


def _check_path(x: np.ndarray, where: str) -> None:
    """Refuse, in one line, a repetition that strays from the others' median path by more than
    ``PATH_TOLERANCE`` (RMS over the record)."""
    median = np.median(x, axis=0)
    stray = np.sqrt(np.mean(np.sum((x - median) ** 2, axis=2), axis=1))
    worst = int(np.argmax(stray))
    if stray[worst] > PATH_TOLERANCE:
        raise ValueError(
            f"{where}: repetition {worst} strays {100 * stray[worst]:.1f} cm RMS from the others' median path (more "
            f"than {100 * PATH_TOLERANCE:g} cm): an ensemble holds repetitions of one reach; drop reaches to another "
            "target, or align the repetitions on the movement's onset"
        )


@dataclasses.dataclass(frozen=True, eq=False)
class Ensemble:
    """``R`` repetitions of one reach, sampled every ``period`` (NumPy arrays).

    Args:
        x: hand positions [m], ``(R, N, 2)`` (or a list of ``R`` ``(N, 2)`` arrays of one length).
        fh: hand forces [N] (the force on the hand, as ``simulate`` records it), shaped as ``x``.
        f_delta: the perturbations [N], shaped as ``x``, or ``None`` (unknown: the estimate
            then judges a knot's perturbation by the hand's motion).
        period: the sample period [s] (default 1 ms).
        trial: the simulated reach (``simulate_ensemble``'s ``Trial``: its arm is the truth), or
            ``None`` for a lab's recordings.
        diverged: ``(R,)`` bool, the simulated repetitions that diverged, or ``None``.

    Refused in one line: shapes that differ, fewer than two repetitions, values that are not
    finite, repetitions of different lengths, a repetition whose path strays more than
    ``PATH_TOLERANCE`` from the others' median (a reach to another target, or one not aligned
    on its onset).
    """

    x: Any
    fh: Any
    f_delta: Any = None
    period: float = CONTROL_PERIOD
    trial: Any = None
    diverged: Any = None

    def __post_init__(self):
        w, set_ = "Ensemble", object.__setattr__
        set_(self, "x", _repetitions("x", self.x, w))
        set_(self, "fh", _repetitions("fh", self.fh, w))
        if self.f_delta is not None:
            set_(self, "f_delta", _repetitions("f_delta", self.f_delta, w))
        for name in ("fh", "f_delta"):
            value = getattr(self, name)
            if value is not None and value.shape != self.x.shape:
                raise ValueError(f"{w}: {name} must have the shape of x {self.x.shape}, got {value.shape}")
        if self.x.shape[0] < 2 or self.x.shape[1] < 3:
            raise ValueError(f"{w}: needs at least 2 repetitions of 3 samples or more, got x of shape {self.x.shape}")
        if not (isinstance(self.period, (int, float)) and 0 < self.period < np.inf):
            raise ValueError(f"{w}: period must be a positive number of seconds, got {self.period!r}")
        set_(self, "period", float(self.period))
        if self.diverged is not None:
            set_(self, "diverged", np.asarray(self.diverged, dtype=bool).reshape(self.x.shape[0]))
        _check_path(self.sound().x, w)

    @property
    def repetitions(self) -> int:
        """``R``, the number of repetitions (diverged ones included)."""
        return int(self.x.shape[0])

    @property
    def samples(self) -> int:
        """``N``, the samples per repetition."""
        return int(self.x.shape[1])

    @property
    def times(self) -> np.ndarray:
        """The sample times ``k * period`` [s], ``(N,)``."""
        return np.arange(self.samples) * self.period

    def sound(self) -> Ensemble:
        """The ensemble without its diverged repetitions (itself when none diverged)."""
        if self.diverged is None or not self.diverged.any():
            return self
        keep = ~self.diverged
        f = None if self.f_delta is None else self.f_delta[keep]
        out = object.__new__(Ensemble)
        for name, value in dict(x=self.x[keep], fh=self.fh[keep], f_delta=f, diverged=None).items():
            object.__setattr__(out, name, value)
        object.__setattr__(out, "period", self.period)
        object.__setattr__(out, "trial", self.trial)
        return out

    @classmethod
    def from_recordings(cls, recordings, *, period: float | None = None) -> Ensemble:
        """The ensemble of a lab's recordings: ``load_recording``'s dictionaries (``x``, ``fh``,
        ``f_delta`` and, where the file has one, ``time``), one per repetition. The period comes
        from ``period`` [s] or else from the first recording's time column (else 1 ms)."""
        recordings = list(recordings)
        if not recordings:
            raise ValueError("Ensemble.from_recordings: no recordings")
        if period is None:
            time = recordings[0].get("time")
            period = float(np.median(np.diff(time))) if time is not None and len(time) > 1 else CONTROL_PERIOD
        return cls(
            x=[r["x"] for r in recordings],
            fh=[r["fh"] for r in recordings],
            f_delta=[r["f_delta"] for r in recordings],
            period=period,
        )
