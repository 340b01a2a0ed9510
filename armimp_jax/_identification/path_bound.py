"""The Cramér-Rao bound along a reach, and the number of reaches a lab needs: ``reaches_for``.

One repetition of a reach records ``y_r = mu(theta, f_r) + v_r``: the noise-free response to its own
perturbation ``f_r`` and the response ``v_r`` to the noise, non-stationary along the path
(``path.py``). An ensemble subtracts its mean at each sample: the mean path is a free nuisance (a lab
does not know the person's equilibrium path to the millimetre), and what is left informs ``theta``
through the response to the perturbation alone. With the noise whitened by the time-varying filter,

    I_1(theta) = E_f [ sum_k de_k^T de_k ],   de = whiten(d mu(theta, f) / d theta - d mu(theta, 0) / d theta),

the information of one repetition (the expectation over the perturbation's draws, estimated by the
draws given). ``R`` independent repetitions less their mean carry ``(R - 1) I_1`` (the mean path, a
nuisance per sample, takes one repetition's worth; docs/model.md section 19): the bound on a knot's
entry is ``se_1 / sqrt(R - 1)``. ``reaches_for`` inverts that for a precision.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
from scipy.stats import norm

from .._checks import as_float64, require_x64
from .._estimation.welch import check_finite
from .._simulate import Trial
from . import path as ph
from .indirect import IDENTIFY_NUMERICS

MAX_REACHES = 100_000  # beyond this a precision is out of a lab's reach; reported as such


def check_draws(f, where: str) -> np.ndarray:
    """``f`` as float64 ``(D, N, 2)`` perturbation draws (an ``(N, 2)`` one is one draw); one-line errors."""
    f = as_float64("f", f, where=where)
    f = f[None] if f.ndim == 2 else f
    if f.ndim != 3 or f.shape[2] != 2 or f.shape[1] < 8:
        raise ValueError(f"{where}: f must have shape (N, 2) or (D, N, 2) with N >= 8 samples, got {f.shape}")
    check_finite("f", f, where=where)
    if not np.any(f != 0):
        raise ValueError(f"{where}: f is zero: a reach without perturbation tells nothing of the arm")
    return f


@functools.partial(jax.jit, static_argnames=("layout", "numerics"))
def whitened_jacobians(layout: ph.KnotLayout, trial: Trial, p, f, numerics):
    """``de`` ``(D, N, 4, n)``: each draw's whitened derivative of its response to the perturbation
    (the response with ``f = 0`` taken out), at ``p``."""
    filt = ph.path_filter(ph.path_loop(ph.with_values(layout, trial, p), f.shape[1], numerics))
    zero = jnp.zeros_like(f[:1])
    jac = ph.response_jacobians(layout, trial, p, jnp.concatenate([zero, f]), numerics)[1]
    return jax.vmap(lambda j: ph.whiten(filt, j - jac[0]))(jac[1:])


def information(trial: Trial, f, *, free=ph.ARM, numerics=None) -> np.ndarray:
    """Fisher information ``(n, n)`` of one repetition of the reach (``KnotLayout``'s entries), the
    mean over the draws ``f`` ``(D, N, 2)`` [N] of the perturbation."""
    layout = ph.knot_layout(trial, free, where="crlb")
    de = whitened_jacobians(layout, trial, ph.pack(layout, trial), jnp.asarray(f), numerics or IDENTIFY_NUMERICS)
    return np.asarray(jnp.einsum("dkip,dkiq->pq", de, de)) / f.shape[0]


@dataclasses.dataclass(frozen=True)
class PathBound:
    """``crlb``'s answer for a reach (host values), for ONE repetition.

    Attributes:
        labels: entry names (``"arm.stiffness@t=0.6[0,0]"``); values: ``(n,)`` the trial's values.
        se: ``(n,)`` the bound on each entry's standard error from one reach's information [the
            entry's unit] (``R`` reaches less their mean: ``se / sqrt(R - 1)``); covariance ``(n, n)``
            and information of one reach.
        draws: the perturbation draws the expectation was taken over; reference: the loop it is of.
    """

    labels: list
    values: np.ndarray
    se: np.ndarray
    covariance: np.ndarray
    information: np.ndarray
    draws: int
    reference: str

    def relative(self, entries=None) -> dict:
        """``{label: se / |value|}`` of one reach, for ``entries`` (default: every diagonal)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            rel = dict(zip(self.labels, self.se / np.abs(self.values), strict=True))
        entries = diagonals(self.labels) if entries is None else list(entries)
        unknown = [e for e in entries if e not in rel]
        if unknown:
            raise ValueError(f"PathBound: unknown entries {unknown}; this bound's: {self.labels}")
        return {e: float(rel[e]) for e in entries}

    def reaches_for(self, precision: float = 0.1, *, level: float = 0.95, entries=None) -> dict:
        """``{label: reaches}`` for ``+- precision`` (relative) at ``level`` on each entry."""
        z = _z(precision, level, "PathBound.reaches_for")
        return {e: _count(z * r / precision) for e, r in self.relative(entries).items()}

    def summary(self) -> str:
        lines = [f"Cramér-Rao bound of one reach ({self.reference}; {self.draws} perturbation draws)"]
        for label, v, s in zip(self.labels, self.values, self.se, strict=True):
            if label.endswith(("[0,0]", "[1,1]")):
                lines.append(f"  {label:32s} {v:10.4g}  SE {s:9.3g} ({s / abs(v):6.1%} of it)")
        return "\n".join(lines)


def inverse(info: np.ndarray, labels, where: str) -> np.ndarray:
    """``info``'s inverse; a one-line error naming the entry the reaches cannot tell (a knot the
    perturbation misses, or two that nothing separates)."""
    w, v = np.linalg.eigh(0.5 * (info + info.T))
    if not np.all(np.isfinite(w)) or w[0] <= 1e-12 * w[-1]:
        worst = labels[int(np.argmax(np.abs(v[:, 0])))]
        raise ValueError(
            f"{where}: the reaches do not tell {worst} (the information is singular there): move that knot or "
            "the perturbation"
        )
    return (v / w[None, :]) @ v.T


def whitened_inverse(wj, labels, where: str) -> np.ndarray:
    """``(sum_r (W J_r)^T W J_r)^-1`` of whitened Jacobians ``wj`` ``(R, N, 4, n)``: the ensemble's GLS
    covariance (``inverse``'s one-line refusal where the reaches cannot tell an entry)."""
    return inverse(np.asarray(jnp.einsum("rkip,rkiq->pq", wj, wj)), labels, where)


def diagonals(labels) -> list[str]:
    return [x for x in labels if x.endswith(("[0,0]", "[1,1]")) and x.startswith("arm.")]


def _z(precision, level, where) -> float:
    if not 0.0 < precision < 1.0:
        raise ValueError(f"{where}: precision must lie in (0, 1) (a fraction of each value), got {precision!r}")
    if not 0.0 < level < 1.0:
        raise ValueError(f"{where}: level must lie in (0, 1), got {level!r}")
    return float(norm.ppf(0.5 + level / 2))


def _count(ratio: float) -> int:
    """Reaches ``R`` with ``ratio / sqrt(R - 1)`` at most 1 (the mean path takes one)."""
    return MAX_REACHES if not ratio**2 < MAX_REACHES else max(2, math.ceil(ratio**2) + 1)


def path_crlb(trial: Trial, f, *, free=ph.ARM, numerics=None) -> PathBound:
    """The bound of one reach of a moving ``trial`` under perturbation draws ``f`` (module docstring)."""
    require_x64("crlb")
    f = check_draws(f, "crlb")
    if not trial.noisy:
        raise ValueError("crlb: the trial has no noise: the bound is 0")
    layout = ph.knot_layout(trial, free, where="crlb")
    ph.check_reach_model(trial, layout, f.shape[1], "crlb")
    info = information(trial, f, free=free, numerics=numerics)
    cov = inverse(info, layout.labels(), "crlb")
    values = np.asarray(ph.pack(layout, trial))
    reference = "the trial's loop without its Coulomb friction" if trial.friction.has_coulomb() else "the trial's loop"
    se = np.sqrt(np.maximum(np.diag(cov), 0.0))
    return PathBound(layout.labels(), values, se, cov, info, int(f.shape[0]), reference)


@dataclasses.dataclass(frozen=True)
class Reaches:
    """``reaches_for``'s answer: ``per_entry`` ``{label: reaches}`` for each knot's diagonal,
    ``worst`` (the largest) and the entry that sets it, at ``precision`` and ``level``; ``bound``
    the ``PathBound`` it came from."""

    per_entry: dict
    worst: int
    limiting: str
    precision: float
    level: float
    bound: PathBound

    def summary(self) -> str:
        lines = [f"Reaches for +-{self.precision:.0%} at {self.level:.0%} on each knot's diagonals (the bound):"]
        lines += [f"  {k:32s} {v:6d}" for k, v in self.per_entry.items()]
        lines.append(f"  worst: {self.worst} reaches ({self.limiting})")
        return "\n".join(lines)


def reaches_for(
    trial: Trial, f, *, precision: float = 0.1, level: float = 0.95, free=ph.ARM, entries=None, numerics=None
) -> Reaches:
    """The repetitions of the reach ``trial`` a lab needs for ``+- precision`` (relative) at
    ``level`` on each knot's diagonals, on the bound (``path_crlb``; an efficient estimator such as
    ``identify`` over the ensemble reaches it), and the worst.

    Args:
        trial: a moving arm's trial at its planned (assumed true) values, with its noise.
        f: the perturbation, ``(D, N, 2)`` [N] draws of it (or one ``(N, 2)``): the information is
            their mean (8 draws of the paper's noise put it within about 2%).
        precision, level: the half-width, relative to each value, and the intervals' level.
        entries: labels to count (default: every diagonal of the free matrices).
    """
    _z(precision, level, "reaches_for")
    bound = path_crlb(trial, f, free=free, numerics=numerics)
    per = bound.reaches_for(precision, level=level, entries=entries)
    limiting = max(per, key=per.get)
    return Reaches(per, per[limiting], limiting, precision, level, bound)
