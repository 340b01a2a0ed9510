"""Figures of the studies: one way to save a figure, and the summary plot of a sweep.

``save_figure(fig, path)`` writes any matplotlib figure atomically (a reader never sees
half a PNG) in the format its suffix names, and closes it if pyplot holds it; every
study (sweeps, the reproduction's figures, recordings) saves through it.
``plot_summary`` draws a sweep's per-point means against a swept setting.
"""

from __future__ import annotations

import io
import pathlib
import sys
from collections.abc import Mapping

import numpy as np

from ..runs.results import atomic_write_bytes
from ..schema.points import default_x, known_settings, point_columns, setting_unit, swept_settings
from .stats import CI_LEVEL


def save_figure(fig, path: pathlib.Path | str, *, dpi: int = 110) -> pathlib.Path:
    """Write ``fig`` (a matplotlib ``Figure``) to ``path`` atomically, in the format of its
    suffix (``.png``, ``.pdf``, ``.svg``) at ``dpi``; close it if pyplot holds it. Layout
    (``tight_layout``, ``layout="constrained"``) is the caller's. Returns ``path``."""
    path = pathlib.Path(path)
    buf = io.BytesIO()
    fig.savefig(buf, format=path.suffix[1:] or "png", dpi=dpi)
    atomic_write_bytes(path, buf.getvalue())
    pyplot = sys.modules.get("matplotlib.pyplot")  # a Figure made without pyplot needs no closing
    if pyplot is not None and getattr(fig.canvas, "manager", None) is not None:
        pyplot.close(fig)
    return path


def plot_summary(summary: list[Mapping], path, *, x: str | None = None, metric: str = "phi_T") -> pathlib.Path:
    """Draw ``metric``'s mean with its 95% interval (a band; none for one seed) against the
    swept numeric setting ``x`` (default: the first swept numeric setting), one line per
    combination of the other swept settings. The x axis is logarithmic when the positive
    values span two decades or more (symlog when 0 is among them); y starts at 0. With no
    numeric setting swept, one bar per point. ``summary``: a sweep's per-point entries
    (``point``, ``stats``). Returns ``path``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    points = [e["point"] for e in summary]
    swept = swept_settings(points)
    if x is None:
        x = default_x(points)
    if x is not None and x not in known_settings():
        raise ValueError(f"cannot plot against {x!r}: not a setting")
    unit = "N/m" if metric.startswith("phi") else ""
    fig, ax = plt.subplots(figsize=(8, 4.5), layout="constrained")
    if x is None:
        labels = [", ".join(f"{k}: {point_columns(p).get(k, '-')}" for k in swept) or "all" for p in points]
        m = [e["stats"][metric]["mean"] for e in summary]
        lo = [e["stats"][metric]["ci_lo"] for e in summary]
        hi = [e["stats"][metric]["ci_hi"] for e in summary]
        err = np.array(
            [
                [mi - a if a == a else 0 for mi, a in zip(m, lo, strict=True)],
                [b - mi if b == b else 0 for mi, b in zip(m, hi, strict=True)],
            ]
        )
        ax.bar(range(len(m)), m, yerr=err, capsize=3)
        ax.set_xticks(range(len(m)), labels, rotation=30, ha="right", fontsize=7)
    else:
        others = [k for k in swept if k != x]
        lines: dict[str, list] = {}
        for e in summary:
            if e["point"][x] is None:  # the setting does not apply to this point (PD's mhat)
                continue
            label = ", ".join(f"{k}: {point_columns(e['point']).get(k, '-')}" for k in others) or metric
            lines.setdefault(label, []).append(e)
        for label, es in lines.items():
            es = sorted(es, key=lambda e: e["point"][x])
            xs = np.array([e["point"][x] for e in es], dtype=float)
            st = [e["stats"][metric] for e in es]
            mean = np.array([s["mean"] for s in st])
            (line,) = ax.plot(xs, mean, "o-", ms=3, label=label)
            lo, hi = np.array([s["ci_lo"] for s in st]), np.array([s["ci_hi"] for s in st])
            if np.isfinite(lo).any():
                ax.fill_between(xs, lo, hi, color=line.get_color(), alpha=0.2, lw=0)
        xs_all = np.array([p[x] for p in points if p[x] is not None], dtype=float)
        pos = xs_all[xs_all > 0]
        if pos.size and pos.max() / pos.min() >= 100:
            if (xs_all == 0).any():
                ax.set_xscale("symlog", linthresh=pos.min(), linscale=0.5)
            else:
                ax.set_xscale("log")
        unit_x = setting_unit(x)
        ax.set_xlabel(f"{x} [{unit_x}]" if unit_x else x)
        if len(lines) > 1 or others:
            ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
    ax.set_ylim(bottom=0)
    ns = sorted({int(e["stats"][metric]["n"]) for e in summary if e["stats"][metric]["n"]})
    seeds = "" if not ns else f"{ns[0]}" if len(ns) == 1 else f"{ns[0]}-{ns[-1]}"
    band = f", {100 * CI_LEVEL:g}% t-interval" if ns and ns[-1] > 1 else ""
    what = f"mean of {seeds} seed{'s' if ns[-1:] != [1] else ''}{band}" if seeds else "mean"
    ax.set_ylabel(f"{metric} [{unit}]" if unit else metric)
    ax.set_title(_fixed_settings(points, swept) + f"\n{metric}: {what}", fontsize=9)
    ax.grid(alpha=0.3)
    return save_figure(fig, path, dpi=120)


_TITLE_NAMES = dict(seconds="record", perturbation_level="perturbation level", force_noise="force noise")
_TITLE_SETTINGS = (
    "controller",
    "friction",
    "arm",
    "tau_c",
    "perturbation_level",
    "peak",
    "seconds",
    "acquisition",
    "force_noise",
)


def _fixed_settings(points: list[Mapping], swept: list[str]) -> str:
    """The settings every point shares that a reader needs to place the figure (one line)."""
    columns = point_columns(points[0])
    parts = []
    for k in _TITLE_SETTINGS:
        value = points[0].get(k)
        if k in swept or value is None or isinstance(value, (dict, list)):
            continue
        unit = setting_unit(k)
        name = _TITLE_NAMES.get(k, k)
        parts.append(f"{name} {columns.get(k, value)}{' ' + unit if unit else ''}")
    return ", ".join(parts)
