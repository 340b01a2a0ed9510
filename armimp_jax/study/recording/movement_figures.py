"""Figures of a lab's day for a movement (``study.recording.movement_day``), each a matplotlib ``Figure``
made without pyplot, printed at 7 x 4.5 in (the caller saves it, ``study.sweep.figures.save_figure``):

- ``path_figure``: the hand's mean path in x-y [cm] and, at each knot, the stiffness ellipse (the
  force per unit displacement: the unit circle mapped through ``K``'s symmetric part, drawn to a
  stated scale in N/m), with its 95% region over angle (``ELLIPSE_DRAWS`` draws of ``K`` from the
  estimate's covariance) and the truth dashed when known: the picture of Burdet et al. (2000),
  Fig. 5.
- ``profile_figure``: ``K(t)`` and ``B(t)`` diagonals with their 95% intervals at the knots
  (joined linearly, as the model is), the truth dashed when known, and the hand's speed shaded
  behind.

Both draw the classical route's ``EnsembleFit`` or, through ``knot_view``, the model route's answer
(``identify`` over an ensemble).
"""

from __future__ import annotations

import dataclasses
import re

import numpy as np
from matplotlib.figure import Figure

from .recording_figures import ELLIPSE_DRAWS, ellipse_radius

SIZE = (7.0, 4.5)  # [in] the printed size
CM = 100.0  # [cm per m]
SCALE_SHARE = 0.2  # the stiffest ellipse's largest semi-axis, as a share of the path's extent
PHI = np.linspace(0.0, 2.0 * np.pi, 361)


def mean_path(ens) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(times [s] (N,), the ensemble's mean hand path [m] (N, 2), its speed [m/s] (N,))``."""
    path = np.asarray(ens.x).mean(axis=0)
    speed = np.linalg.norm(np.gradient(path, ens.period, axis=0), axis=1)
    return ens.times, path, speed


_LABEL = re.compile(r"arm\.(stiffness|damping)(?:@t=([^\[]+))?\[(\d),(\d)\]$")


@dataclasses.dataclass(frozen=True)
class KnotView:
    """The model route's answer as the figures read a fit: ``knots`` [s] ``(J,)``, ``stiffness`` and
    ``damping`` ``(J, 2, 2)``, each knot's ``K`` entries' covariance ``(J, 4, 4)`` (row-major), and
    every entry's interval by the answer's own ``interval`` (a constant matrix repeated at each knot)."""

    knots: np.ndarray
    stiffness: np.ndarray
    damping: np.ndarray
    stiffness_covariance: np.ndarray
    fit: object
    where: dict

    def interval(self, name: str, level: float = 0.95) -> tuple[np.ndarray, np.ndarray]:
        low, high = np.empty((2, self.knots.size, 2, 2))
        for (j, a, b), label in self.where[name].items():
            low[j, a, b], high[j, a, b] = self.fit.interval(label, level)
        return low, high


def knot_view(fit) -> KnotView | None:
    """``fit`` (``identify`` over an ensemble) on its stiffness's knots, or None unless the stiffness
    is a profile and the damping, free, is constant or a profile on the same knots (nothing to draw
    together otherwise)."""
    found = {"stiffness": {}, "damping": {}}  # (knot time or None for a constant, row, column) -> label
    for label in fit.labels:
        m = _LABEL.match(label)
        if m:
            found[m[1]][(None if m[2] is None else float(m[2]), int(m[3]), int(m[4]))] = label
    knots = sorted({t for t, _, _ in found["stiffness"]} - {None})
    damping_times = {t for t, _, _ in found["damping"]}
    if not knots or None in {t for t, _, _ in found["stiffness"]} or damping_times not in ({None}, set(knots)):
        return None
    where = {
        name: {
            (j, a, b): cells.get((t, a, b), cells.get((None, a, b)))
            for j, t in enumerate(knots)
            for a in range(2)
            for b in range(2)
        }
        for name, cells in found.items()
    }
    index = {label: i for i, label in enumerate(fit.labels)}
    value = {name: np.zeros((len(knots), 2, 2)) for name in where}
    for name, cells in where.items():
        for (j, a, b), label in cells.items():
            value[name][j, a, b] = fit.estimate[index[label]]
    cov = np.asarray(fit.covariance)
    k_index = [[index[where["stiffness"][(j, a, b)]] for a in range(2) for b in range(2)] for j in range(len(knots))]
    k_cov = np.stack([cov[np.ix_(idx, idx)] for idx in k_index])
    return KnotView(np.asarray(knots), value["stiffness"], value["damping"], k_cov, fit, where)


def stiffness_draws(fit, n: int = ELLIPSE_DRAWS, seed: int = 0) -> np.ndarray:
    """``n`` draws of every knot's ``K`` ``(J, n, 2, 2)`` from the normal approximation: each force
    axis's row from its covariance (``EnsembleFit.covariance``; the two axes are fitted apart), or
    (a ``KnotView``) every entry from the knot's joint covariance."""
    rng = np.random.default_rng(seed)
    knots = np.asarray(fit.knots).size
    if isinstance(fit, KnotView):
        out = np.empty((knots, n, 2, 2))
        for j in range(knots):
            w, v = np.linalg.eigh(fit.stiffness_covariance[j])
            z = rng.standard_normal((n, 4)) * np.sqrt(np.clip(w, 0.0, None))
            out[j] = (fit.stiffness[j].reshape(4) + z @ v.T).reshape(n, 2, 2)
        return out
    out = np.empty((knots, n, 2, 2))
    for j in range(knots):
        idx = slice(4 + 4 * j, 6 + 4 * j)  # K_j's row in each axis's parameters
        for i in range(2):
            cov = np.asarray(fit.covariance)[i, idx, idx]
            w, v = np.linalg.eigh(cov)
            z = rng.standard_normal((n, 2)) * np.sqrt(np.clip(w, 0.0, None))
            out[j, :, i, :] = np.asarray(fit.stiffness)[j, i] + z @ v.T
    return out


def ellipse_curve(k, scale: float, phi=PHI) -> np.ndarray:
    """The stiffness ellipse of ``k`` ``(2, 2)`` as ``(len(phi), 2)`` points: ``scale`` times the
    force ``K_s d`` [N/m] for unit displacements ``d`` at angles ``phi`` (``K_s`` the symmetric part)."""
    k = np.asarray(k, dtype=float)
    sym = 0.5 * (k + k.T)
    return scale * np.stack([np.cos(phi), np.sin(phi)], axis=1) @ sym.T


def _nice(value: float) -> float:
    """The round number (1, 2 or 5 times a power of ten) at or below ``value`` > 0."""
    power = 10.0 ** np.floor(np.log10(value))
    return max(m for m in (1.0, 2.0, 5.0) if m * power <= value) * power


def _largest(fit, true) -> float:
    """The largest ``|eigenvalue|`` [N/m] of the knots' symmetric ``K`` (estimates and truth)."""
    ks = [np.asarray(fit.stiffness)] + ([np.asarray(true["stiffness"])] if true is not None else [])
    return float(max(np.max(np.abs(np.linalg.eigvalsh(0.5 * (k + np.swapaxes(k, -1, -2))))) for k in ks))


def path_figure(ens, fit, true=None, *, draws=None):
    """(a) The stiffness ellipses along the path (module docstring); ``ens``: the (sound) ensemble,
    ``fit``: its ``EnsembleFit``, ``true``: the simulated arm at the knots (``movement_day.truth``)."""
    times, path, _ = mean_path(ens)
    knots = np.asarray(fit.knots)
    centre = CM * np.stack([np.interp(knots, times, path[:, a]) for a in range(2)], axis=1)
    largest = _largest(fit, true)
    scale = SCALE_SHARE * max(float(np.ptp(CM * path, axis=0).max()), 2.0) / largest  # [cm per N/m]
    draws = stiffness_draws(fit) if draws is None else draws
    colours = _colours(knots.size)
    fig = Figure(figsize=SIZE, layout="constrained")
    ax = fig.subplots()
    ax.plot(CM * path[:, 0], CM * path[:, 1], color="0.45", lw=1.0, label="mean hand path")
    for j, (c, colour) in enumerate(zip(centre, colours, strict=True)):
        lo, hi = np.nanpercentile(ellipse_radius(draws[j], PHI), [2.5, 97.5], axis=0)
        ring = np.r_[hi, lo[::-1]] * scale, np.r_[PHI, PHI[::-1]]
        ax.fill(c[0] + ring[0] * np.cos(ring[1]), c[1] + ring[0] * np.sin(ring[1]), color=colour, alpha=0.25, lw=0)
        e = c + ellipse_curve(fit.stiffness[j], scale)
        ax.plot(e[:, 0], e[:, 1], color=colour, lw=1.4, label=f"t = {knots[j]:g} s", gid=f"estimate-{j}")
        if true is not None:
            e = c + ellipse_curve(true["stiffness"][j], scale)
            ax.plot(e[:, 0], e[:, 1], "--", color=colour, lw=0.9, gid=f"truth-{j}")
        ax.plot(*c, "o", color=colour, ms=3)
    _scale_bar(ax, scale, largest)
    ax.plot([], [], color="0.3", alpha=0.35, lw=6, label="95% region")
    if true is not None:
        ax.plot([], [], "k--", lw=0.9, label="truth (simulated)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("hand x [cm]")
    ax.set_ylabel("hand y [cm]")
    ax.set_title("stiffness ellipses along the reach (symmetric part of K)", fontsize=10)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.02, 1.0), frameon=False)
    ax.grid(alpha=0.3)
    return fig


def _colours(n: int):
    import matplotlib

    return matplotlib.colormaps["viridis"](np.linspace(0.0, 0.85, n))


def _scale_bar(ax, scale: float, largest: float) -> None:
    """A bar of a round stiffness [N/m] at or below the ``largest``, at ``scale`` [cm per N/m]."""
    from matplotlib.font_manager import FontProperties
    from mpl_toolkits.axes_grid1.anchored_artists import AnchoredSizeBar

    value = _nice(largest)
    bar = AnchoredSizeBar(
        ax.transData,
        value * scale,
        f"{value:g} N/m",
        "lower right",
        frameon=False,
        size_vertical=0.08,
        fontproperties=FontProperties(size=8),
        pad=0.4,
    )
    ax.add_artist(bar)


def _band(ax, knots, value, low, high, colour, label):
    ax.fill_between(knots, low, high, color=colour, alpha=0.2, lw=0)
    ax.errorbar(knots, value, yerr=[value - low, high - value], fmt="o-", color=colour, ms=3, lw=1.2, capsize=2)
    if label is not None:
        ax.plot([], [], "o-", color=colour, ms=3, label=label)


def profile_figure(ens, fit, true=None):
    """(b) ``K`` and ``B`` diagonals against time (module docstring)."""
    times, _, speed = mean_path(ens)
    knots = np.asarray(fit.knots)
    fig = Figure(figsize=SIZE, layout="constrained")
    axes = fig.subplots(2, 1, sharex=True)
    colours = ("tab:blue", "tab:orange")
    for ax, (sym, name, unit) in zip(axes, (("K", "stiffness", "N/m"), ("B", "damping", "N s/m")), strict=True):
        shade = ax.twinx()
        shade.fill_between(times, CM * speed, color="0.88", lw=0)
        shade.set_ylim(0.0, 1.1 * CM * max(speed.max(), 1e-9))
        shade.set_ylabel("speed [cm/s]", fontsize=8, color="0.45")
        shade.tick_params(labelsize=8, colors="0.45")
        ax.set_zorder(shade.get_zorder() + 1)
        ax.patch.set_visible(False)
        value, (low, high) = np.asarray(getattr(fit, name)), fit.interval(name, 0.95)
        for a, colour in enumerate(colours):
            label = f"K$_{{{'xy'[a] * 2}}}$, B$_{{{'xy'[a] * 2}}}$"
            _band(ax, knots, value[:, a, a], low[:, a, a], high[:, a, a], colour, label if sym == "K" else None)
            if true is not None:
                t = np.r_[times[0], knots, times[-1]]
                v = np.asarray(true[name])[:, a, a]
                ax.plot(t, np.r_[v[0], v, v[-1]], "--", color=colour, lw=0.9)
        ax.set_ylabel(f"{sym} [{unit}]")
        ax.grid(alpha=0.3)
        ax.tick_params(labelsize=8)
    if true is not None:
        axes[0].plot([], [], "k--", lw=0.9, label="truth (simulated)")
    axes[0].fill_between([], [], color="0.88", label="hand speed")
    axes[0].legend(fontsize=7, ncols=5, loc="lower center", bbox_to_anchor=(0.5, 1.0), frameon=False)
    axes[-1].set_xlabel("time [s]")
    axes[-1].set_xlim(times[0], times[-1])
    fig.suptitle(
        "diagonals of K and B at the knots: 95% intervals (bars), joined linearly as the model is", fontsize=10
    )
    return fig
