"""The friction threshold: how much Coulomb friction a robot may have before it spoils the estimate.

phi_T and the minimum multiple coherence against the Coulomb torque tau_c from 0 to 4 N m
(0, log-spaced points from 1e-3 to 4 N m, plus the reference torques 0.05, 1 and 4 N m;
stiction 1.5 tau_c, the paper's bristle and viscous parameters), PD and IMBIC (Mhat = 0.25 I
kg), the four paper arms, perturbation level 1, seeds with common random numbers,
``SWEEP_NUMERICS`` (ARK3, 20 substeps). The study is a sweep (``threshold_settings``, run by
``study.sweep.sweep.run_sweep`` on the study engine); ``analyse`` finds the thresholds
(``stats.bootstrap_crossing``), ``plot`` draws ``friction_threshold.png`` and ``write_report``
writes ``report.md`` (``run_threshold`` does all of it).
"""

from __future__ import annotations

import math
import pathlib
import time
import warnings

import numpy as np

from ..runs.results import atomic_write_text, package_version
from ..schema.grids import expand
from .figures import save_figure
from .stats import bootstrap, bootstrap_crossing, seed_stats
from .sweep import SweepSettings, collect, run_sweep

REFERENCES = ((0.05, "direct drive"), (1.0, "paper level 1"), (4.0, "paper level 2"))
STICTION_RATIO = 1.5
COHERENCE_LEVEL = 0.9
PHI_RATIO = 2.0


def tau_grid(points: int) -> list[float]:
    """0, ``points`` log-spaced values in [1e-3, 4] N m, and the reference torques, sorted; a
    log-spaced value within 25% of a reference torque is replaced by it (no near-duplicates)."""
    refs = [r for r, _ in REFERENCES]
    grid = [float(v) for v in np.geomspace(1e-3, 4.0, points)]
    grid = [v for v in grid if all(abs(math.log(v / r)) > math.log(1.25) for r in refs)]
    return sorted({0.0, *grid, *refs})


def threshold_settings(
    *, seconds: float, nperseg: int, seeds: int, points: int, method: str | None = None, substeps: int | None = None
) -> SweepSettings:
    """The threshold's sweep: PD and IMBIC at the four paper arms over ``tau_grid(points)``
    (stiction ``STICTION_RATIO`` tau_c), records of ``seconds`` [s], Welch segments of
    ``nperseg`` samples (overlap 3/4), ``seeds`` per point; ``method`` and ``substeps``
    default to ``SWEEP_NUMERICS``'s."""
    grid = dict(
        controller=["pd", "imbic"],
        arm=[1, 2, 3, 4],
        tau_c=tau_grid(points),
        stiction_ratio=[STICTION_RATIO],
        seconds=[seconds],
        nperseg=[nperseg],
    )
    run = dict(seeds=seeds)
    if method is not None:
        run["method"] = method
    if substeps is not None:
        run["substeps"] = substeps
    return SweepSettings(tuple(expand(grid)), **run)


# --- analysis ------------------------------------------------------------------------------


def curves(settings, rows):
    """``{(controller, arm): (taus (P,), phi (S, P), coh (S, P))}`` with NaN for diverged trials."""
    out = {}
    for ctrl in ("pd", "imbic"):
        for arm in (1, 2, 3, 4):
            sel = [r for r in rows if r["controller"] == ctrl and r["arm"] == arm]
            taus = sorted({r["tau_c"] for r in sel})
            phi = np.full((settings.seeds, len(taus)), np.nan)
            coh = np.full_like(phi, np.nan)
            for r in sel:
                if not r["diverged"]:
                    phi[r["seed"], taus.index(r["tau_c"])] = r["phi_T"]
                    coh[r["seed"], taus.index(r["tau_c"])] = r["coh_min"]
            out[ctrl, arm] = (np.array(taus), phi, coh)
    return out


def ratio_band(phi, *, n_boot: int = 2000, seed: int = 0):
    """Mean phi_T / mean phi_T(tau_c = 0) per grid point and its percentile 95% bootstrap band
    over seeds (seeds resampled whole)."""

    def ratio(v):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            m = np.nanmean(v, axis=0)
        return m / m[0]

    mean = ratio(phi)
    s = phi.shape[0]
    if s < 2:
        return mean, np.full_like(mean, np.nan), np.full_like(mean, np.nan)
    boots = bootstrap(phi, ratio, n_boot=n_boot, seed=seed)
    lo, hi = np.nanquantile(boots, [0.025, 0.975], axis=0)
    return mean, lo, hi


def _fmt_tau(c: dict) -> str:
    if math.isnan(c["value"]):
        return "not reached within 0-4 N m"
    if c["value"] == 0.0:
        return "already at tau_c = 0"
    v = f"{c['value']:.3g}"
    if c["seeds"] < 2:
        return f"{v} (1 seed: no interval)"
    hi = "> 4" if math.isinf(c["ci_hi"]) else f"{c['ci_hi']:.3g}"
    return f"{v} [{c['ci_lo']:.3g}, {hi}]"


def analyse(settings, rows):
    """Per (controller, arm): phi_T(0), the two thresholds (``stats.bootstrap_crossing``), and
    the curves' values at the reference torques."""
    table = {}
    for (ctrl, arm), (taus, phi, coh) in curves(settings, rows).items():
        mean_r, lo_r, hi_r = ratio_band(phi)
        with np.errstate(all="ignore"):
            coh_mean = np.nanmean(coh, axis=0) if np.isfinite(coh).any() else np.full(len(taus), np.nan)
        refs = {}
        for tau, _ in REFERENCES:
            j = int(np.argmin(np.abs(taus - tau)))
            refs[tau] = dict(ratio=mean_r[j], lo=lo_r[j], hi=hi_r[j], coh=coh_mean[j], coh_stats=seed_stats(coh[:, j]))
        table[ctrl, arm] = dict(
            taus=taus,
            phi0=seed_stats(phi[:, 0]),
            coh0=seed_stats(coh[:, 0]),
            ratio=(mean_r, lo_r, hi_r),
            coh=coh,
            phi_threshold=bootstrap_crossing(taus, phi, lambda m: PHI_RATIO * m[0], above=True),
            coh_threshold=bootstrap_crossing(taus, coh, lambda m: COHERENCE_LEVEL, above=False),
            refs=refs,
            diverged=int(np.sum(~np.isfinite(phi))),
        )
    return table


def plot(table, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 2, figsize=(11, 7.5), sharex=True)
    for col, ctrl in enumerate(("pd", "imbic")):
        ax_phi, ax_coh = axes[0, col], axes[1, col]
        for arm in (1, 2, 3, 4):
            t = table[ctrl, arm]
            taus = t["taus"]
            mean, lo, hi = t["ratio"]
            (line,) = ax_phi.plot(taus, mean, "o-", ms=3, label=f"arm location {arm}")
            if np.isfinite(lo).any():
                ax_phi.fill_between(taus, lo, hi, color=line.get_color(), alpha=0.2, lw=0)
            st = [seed_stats(t["coh"][:, j]) for j in range(len(taus))]
            ax_coh.plot(taus, [s["mean"] for s in st], "o-", ms=3, color=line.get_color(), label=f"arm location {arm}")
            clo = np.array([s["ci_lo"] for s in st])
            if np.isfinite(clo).any():
                ax_coh.fill_between(taus, clo, [s["ci_hi"] for s in st], color=line.get_color(), alpha=0.2, lw=0)
        ax_phi.axhline(PHI_RATIO, color="k", ls=":", lw=1)
        ax_coh.axhline(COHERENCE_LEVEL, color="k", ls=":", lw=1)
        ax_phi.set_title(f"{ctrl.upper()}")
        ax_phi.set_ylabel("phi_T / phi_T(tau_c=0), mean, 95% CI")
        ax_coh.set_ylabel("min multiple coherence, mean, 95% CI")
        ax_coh.set_xlabel("Coulomb torque tau_c [N m] (stiction 1.5 tau_c)")
        top = max(float(np.nanmax(table[ctrl, arm]["ratio"][0])) for arm in (1, 2, 3, 4))
        if top > 10:  # a ratio that spans decades: log y (the 2x line stays readable)
            ax_phi.set_yscale("log")
        else:
            ax_phi.set_ylim(bottom=0)
        ax_coh.set_ylim(0, 1.02)
        for ax in (ax_phi, ax_coh):
            ax.set_xscale("symlog", linthresh=1e-3, linscale=0.5)
            ax.grid(alpha=0.3)
            for tau, label in REFERENCES:
                ax.axvline(tau, color="grey", ls="--", lw=0.8)
                if ax is ax_phi:
                    ax.text(
                        tau,
                        0.98,
                        f" {label}",
                        rotation=90,
                        va="top",
                        ha="right",
                        fontsize=7,
                        transform=ax.get_xaxis_transform(),
                    )
        ax_phi.legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    return save_figure(fig, path, dpi=120)


def write_report(settings, result, table, out, wall_s: float, figure) -> pathlib.Path:
    s = settings
    p = s.points[0]
    version = package_version()
    taus = table["pd", 1]["taus"]
    lines = [
        "# The friction threshold",
        "",
        f"armimp_jax {version}; {len(s.points)} points x {s.seeds} seeds = {len(s.points) * s.seeds} trials of "
        f"{s.points[0]['seconds']:g} s, Welch {s.points[0]['nperseg']}/{s.points[0]['noverlap']} samples to "
        f"{s.points[0]['fmax']:g} Hz, {s.method} with {s.substeps} substeps per 1 ms; this call "
        f"computed {len(result['computed'])} trials in {wall_s:.0f} s. Perturbation level 1 (2.25 N per axis), "
        "IMBIC Mhat = 0.25 I kg, LuGre with "
        f"tau_s = {STICTION_RATIO} tau_c, sigma0 = {p['sigma0']:g}, sigma1 = {p['sigma1']:g}, sigma2 = "
        f"{p['sigma2']:g}, v_s = {p['v_s']:g} (the paper's bristle and viscous parameters at every point, so "
        "tau_c = 0 keeps the viscous term).",
        "",
        f"tau_c grid [N m]: {', '.join(f'{t:.3g}' for t in taus)}.",
        "",
        "Definitions:",
        "",
        f"- **phi_T threshold**: the smallest tau_c at which the seed-mean phi_T reaches {PHI_RATIO:g}x its "
        "tau_c = 0 value (the same seeds, common random numbers).",
        f"- **coherence threshold**: the smallest tau_c at which the seed mean of the minimum multiple coherence "
        f"falls below {COHERENCE_LEVEL}; the minimum is over 0 < f <= fmax and over the four multiple coherences "
        "(both position outputs and both force outputs) that Z = T R^-1 is built from (`coh_min`).",
        "- Between grid points the curve is interpolated linearly in log tau_c (linearly from tau_c = 0).",
        "- Intervals: 95% percentile bootstrap over seeds (2000 resamples, seeds resampled whole, the threshold "
        "recomputed from each resample's mean curve); '> 4' when more than 2.5% of the resamples never cross. With "
        "few seeds the intervals are rough.",
        "- Diverged trials are left out of every mean (count per row below).",
        "",
        "| controller | arm | phi_T(0) [N/m] | tau_c at 2x phi_T(0) [N m] (95% CI) | coh_min(0) | tau_c at coh_min "
        "< 0.9 [N m] (95% CI) | phi_T ratio at 0.05 / 1 / 4 N m | coh_min at 0.05 / 1 / 4 N m | diverged |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for (ctrl, arm), t in table.items():
        p0 = t["phi0"]
        ratios = " / ".join(f"{t['refs'][tau]['ratio']:.3g}" for tau, _ in REFERENCES)
        cohs = " / ".join(f"{t['refs'][tau]['coh']:.3f}" for tau, _ in REFERENCES)
        lines.append(
            f"| {ctrl.upper()} | {arm} | {p0['mean']:.4g} | {_fmt_tau(t['phi_threshold'])} | {t['coh0']['mean']:.3f} | "
            f"{_fmt_tau(t['coh_threshold'])} | {ratios} | {cohs} | {t['diverged']} |"
        )
    chk = result.get("numerics_check")
    lines += [
        "",
        f"The direct-drive robot's ~0.05 N m and the paper's friction levels 1 and 2 (1 and 4 N m) are grid points; "
        f"the figure marks them. `{figure.name}`: top, phi_T over its tau_c = 0 value (bootstrap band); bottom, the "
        "minimum multiple coherence (t-interval band); dotted lines at the thresholds.",
        "",
        f"![friction threshold]({figure.name})",
        "",
        "Numerics check: "
        + (
            f"{chk['trials_checked']} trials re-run at {chk['refined_substeps']} substeps, max relative phi_T error "
            f"{chk['max_rel_error']:.2g}."
            if chk and chk.get("max_rel_error") is not None
            else "not run (--check N re-runs N trials per controller at 4x the substeps)."
        ),
        "",
        f"Complete: {result['complete']} ({result['trials']} of {result['trials_expected']} trials); "
        f"{len(result['diverged'])} diverged. Per-trial numbers: `trials.csv`; per-point statistics: `summary.csv`.",
        "",
    ]
    path = pathlib.Path(out) / "report.md"
    atomic_write_text(path, "\n".join(lines))
    return path


def run_threshold(settings: SweepSettings, out, *, batch_size: int = 64, check: int = 0, console=None, warn=None):
    """Run (or resume) the threshold's sweep in ``out`` (``run_sweep``), then analyse it, draw
    ``friction_threshold.png`` and write ``report.md``; returns ``(sweep result, report path)``."""
    start = time.perf_counter()
    options = dict(batch_size=batch_size, check=check, x="tau_c", console=console)
    result = run_sweep(settings, out, **options, **({} if warn is None else dict(warn=warn)))
    wall = time.perf_counter() - start
    rows, _ = collect(settings, out, warn=lambda _: None)
    table = analyse(settings, rows)
    figure = plot(table, pathlib.Path(out) / "friction_threshold.png")
    return result, write_report(settings, result, table, out, wall, figure)
