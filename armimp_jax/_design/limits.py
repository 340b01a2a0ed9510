"""What a clinician allows in an experiment (``Limits``) and the perturbation that meets them
by construction: ``limited_signal`` sets the RMS, clips the peaks and scales the whole signal
until the hand's peak displacement in every arm's noise-free simulation is within its limit."""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

from .._checks import require_x64
from .._identification.indirect import IDENTIFY_NUMERICS
from .._model.sensors import quiet
from .._model.timing import CONTROL_PERIOD
from .._pytree import replace_unchecked
from .._simulate import Trial, simulate

DISPLACEMENT_TOLERANCE = 1e-3  # of the gain, in the displacement limit's bisection
CLIP_ITERATIONS = 40  # clip-and-rescale passes of the peak limit: a few for Gaussian noise, ~30 for short bursts


@dataclasses.dataclass(frozen=True)
class Limits:
    """What a clinician allows: ``rms_force`` and ``peak_force`` [N] per axis of the
    perturbation ``F_Delta`` (scalars or ``(2,)``), ``peak_displacement`` [m] of the hand
    from its rest position in the noise-free simulation (``None``: no limit; the person's own
    force moves the hand further: a design reports that peak plus three RMS drifts), and the
    record length ``record`` [s]. For a design of the controller too: ``drift`` [m], the largest RMS
    length of the hand's displacement under the person's own force (``None``: no limit), and
    ``min_stiffness`` [N/m] and ``min_damping`` [N s/m], the least diagonal desired stiffness
    and damping (IMBIC's ``k_rd``, ``b_rd``; PD's ``kp``, ``kv``)."""

    rms_force: float | tuple
    peak_force: float | tuple
    record: float
    peak_displacement: float | None = None
    drift: float | None = None
    min_stiffness: float = 0.0
    min_damping: float = 0.0

    def __post_init__(self):
        rms = np.broadcast_to(np.asarray(self.rms_force, dtype=float), (2,))
        peak = np.broadcast_to(np.asarray(self.peak_force, dtype=float), (2,))
        if not np.all(rms > 0) or not np.all(np.isfinite(peak)):
            raise ValueError(
                f"Limits: rms_force must be > 0 N and peak_force finite, got {rms.tolist()}, {peak.tolist()}"
            )
        if np.any(peak < rms):
            raise ValueError(
                f"Limits: no signal meets peak_force {peak.tolist()} N below rms_force {rms.tolist()} N "
                "(a peak is at least the RMS)"
            )
        if not (math.isfinite(self.record) and self.record >= 2.0):
            raise ValueError(f"Limits: record must be >= 2 s, got {self.record}")
        if self.peak_displacement is not None and not self.peak_displacement > 0:
            raise ValueError(f"Limits: peak_displacement must be > 0 m or None, got {self.peak_displacement}")
        if self.drift is not None and not self.drift > 0:
            raise ValueError(f"Limits: drift must be > 0 m or None, got {self.drift}")
        for name in ("min_stiffness", "min_damping"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"Limits: {name} must be finite and >= 0, got {v}")

    def n_samples(self, period: float) -> int:
        return int(round(self.record / period))


def _quiet(trial: Trial) -> Trial:
    return replace_unchecked(trial, sensors=quiet(trial.sensors), voluntary=None)


@jax.jit
def _peak_displacement(trial, f):
    sim = simulate(_quiet(trial), f, numerics=IDENTIFY_NUMERICS)
    return jnp.max(jnp.linalg.norm(sim.x - trial.x0[None, :], axis=1)), sim.diverged


def _limited_signal(family, key, n, limits: Limits, period: float, gain=1.0):
    """The family's signal at ``rms_force`` with its peaks clipped to ``peak_force`` (the rest
    re-scaled so that the RMS stays at its limit), times ``gain``."""
    rms = jnp.broadcast_to(jnp.asarray(limits.rms_force, dtype=jnp.float64), (2,))
    peak = jnp.broadcast_to(jnp.asarray(limits.peak_force, dtype=jnp.float64), (2,))
    s = replace_unchecked(family, rms=rms).signal(key, n, period)
    peak = peak[None, :]

    def clip_and_rescale(_, s):
        c = jnp.clip(s, -peak, peak)
        return c * (rms / jnp.sqrt(jnp.mean(c * c, axis=0)))[None, :]

    # the fixed point has the RMS at its limit and the peak within it; a last clip makes the
    # peak exact whatever is left of the iteration (then the RMS is a hair below its limit)
    s = jnp.clip(jax.lax.fori_loop(0, CLIP_ITERATIONS, clip_and_rescale, s), -peak, peak)
    return s * gain


def limited_signal(family, limits: Limits, *, key, period: float = CONTROL_PERIOD, trials=None) -> np.ndarray:
    """The ``(N, 2)`` force [N] a family gives within ``limits``, as ``design`` makes it: at
    ``rms_force``, peaks clipped to ``peak_force`` (the rest re-scaled to keep the RMS), and,
    with ``trials`` and a ``peak_displacement``, scaled down until the hand's peak
    displacement in every trial's noise-free simulation is within it. ``N`` from
    ``limits.record`` and ``period`` [s]; ``key`` draws the family's noise (``design``'s
    start uses ``jax.random.split(key)[0]`` of its own key)."""
    require_x64("limited_signal")
    n = limits.n_samples(period)
    gain = 1.0 if trials is None else _displacement_gain(family, key, n, limits, list(trials), period)
    return np.asarray(_limited_signal(family, key, n, limits, period, gain))


def _displacement_gain(family, key, n, limits, trials, period):
    """The largest gain <= 1 (to ``DISPLACEMENT_TOLERANCE``) at which every trial's peak hand
    displacement is within the limit, by bisection: with friction the motion is far from
    proportional to the force (the joints stick below their breakaway torque)."""
    if limits.peak_displacement is None:
        return 1.0

    def within(gain):
        f = _limited_signal(family, key, n, limits, period, gain)
        peaks = [_peak_displacement(t, f) for t in trials]
        return not any(bool(d) for _, d in peaks) and max(float(p) for p, _ in peaks) <= limits.peak_displacement

    if within(1.0):
        return 1.0
    low, high = 0.0, 1.0
    while high - low > DISPLACEMENT_TOLERANCE:
        mid = 0.5 * (low + high)
        low, high = (mid, high) if within(mid) else (low, mid)
    if low == 0.0:
        raise ValueError(
            f"design: the hand's displacement stays above peak_displacement {limits.peak_displacement} m even at "
            f"{DISPLACEMENT_TOLERANCE:g} of the force limits; raise it or lower the force limits"
        )
    return low
