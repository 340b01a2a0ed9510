"""The Welch route for a lab's recording (``sweeps/estimate_recording.py`` without ``--model``):
its settings, the estimate and fit, the verdict on them, the results on disk.

- ``ROUTE_DEFAULTS``, ``route_settings``: the route's options and what a record decides
  (Welch segments that follow the record, ``welch_segments``; a fitted force-channel delay;
  spectral SEs); ``settings_record``: them as the results record them.
- ``analyse``: ``estimate`` then ``fit_impedance`` on a loaded recording (``study.recording.recording``);
  with ``lines``, the fit weighs only the bins that hold the perturbation's power on both axes
  (``input_bins``: a multisine's lines), where ``Z`` is the arm's.
- ``verdict``: the lack-of-fit test, the VAF and where the perturbation has its power read
  together, in words (a perturbation in few bins, a multisine's lines: the bins between hold
  the person's own force and the noise, and a fit over every bin says nothing of the arm);
  ``intervals``, ``coherence_summary``: what the report and the JSON hold.
- ``write_results``: ``estimate.json`` (strict: non-finite numbers become ``null``),
  ``estimate.npz``, ``bode.png`` and ``coherence.png`` (``study.recording.recording_figures``), each
  written atomically (``study.runs.results.atomic_write_*``, ``study.sweep.figures.save_figure``).

What the script prints is ``study.recording.recording_report``'s.
"""

from __future__ import annotations

import pathlib

import numpy as np

from ..._estimation.diagnose import LACK_OF_FIT_ALPHA, input_coherence_chance
from ..._estimation.estimate import estimate
from ..._estimation.welch import ESTIMATION_FMAX, check_welch, welch_segments
from ..runs.results import atomic_write_json, atomic_write_npz
from ..sweep.figures import save_figure
from .recording_figures import OUTPUTS, bode_figure, coherence_figure


def _summary(f, c) -> dict:
    f, c = np.asarray(f), np.asarray(c)
    k = int(np.nanargmin(c)) if np.any(np.isfinite(c)) else 0
    return {
        "min": c[k],
        "f_at_min_hz": f[k],
        "mean": np.mean(c),
        "median": np.median(c),
        "fraction_above_0_9": np.mean(c > 0.9),
    }


def coherence_summary(est) -> dict:
    """Min (and where), mean, median and fraction above 0.9 of each output's multiple
    coherence over the band, and the largest ordinary coherence of the two inputs with the
    probability that independent inputs reach it by chance (``input_coherence_chance``)."""
    out = {}
    for field, names in OUTPUTS.items():
        mult = np.asarray(getattr(est, f"coh_multiple_{field}"))
        out[f"multiple_{field}"] = {name: _summary(est.f, mult[:, k]) for k, name in enumerate(names)}
    ci = np.asarray(est.coh_inputs)
    out["inputs_max"] = np.max(ci)
    out["inputs_f_at_max_hz"] = np.asarray(est.f)[int(np.argmax(ci))]
    out["inputs_chance_p"] = input_coherence_chance(est)[1]
    return out


ROUTE_DEFAULTS = dict(
    nperseg=None,  # None: segments that follow the record (welch_segments)
    noverlap=None,  # None: 3/4 of nperseg
    nfft=None,  # None: nperseg
    window="hann",
    fmax=ESTIMATION_FMAX,
    weights="uniform",
    acquisition="delay",  # the record's timing unknown: a fitted force-channel delay
    period=None,  # None: 1 / fs
    se="spectral",
)  # the Welch route's options (estimate's, then fit_impedance's) and their defaults


def route_settings(n_samples: int, *, fs: float, **options) -> tuple[dict, dict, int]:
    """The Welch route's settings for a record of ``n_samples`` at ``fs`` [Hz]: ``options``
    (keys of ``ROUTE_DEFAULTS``) over the defaults, with what the record decides filled in.

    Returns ``(welch, fit, n_segments)``: ``estimate``'s keywords (``fs`` included), those of
    ``fit_impedance`` and the number of Welch segments. Raises ``ValueError`` with one line,
    before any computation, for settings that do not go with the record (``check_welch``).
    """
    unknown = sorted(set(options) - set(ROUTE_DEFAULTS))
    if unknown:
        raise ValueError(f"unknown Welch route option(s) {', '.join(unknown)}; they are {', '.join(ROUTE_DEFAULTS)}")
    o = {**ROUTE_DEFAULTS, **options}
    nperseg, noverlap = o["nperseg"], o["noverlap"]
    if nperseg is None:
        nperseg, follows = welch_segments(n_samples)
        noverlap = follows if noverlap is None else noverlap
    elif noverlap is None:
        noverlap = 3 * nperseg // 4
    welch = dict(fs=fs, nperseg=nperseg, noverlap=noverlap, nfft=o["nfft"], window=o["window"], fmax=o["fmax"])
    n_segments = check_welch(n_samples, **welch)
    period = 1.0 / fs if o["period"] is None else o["period"]
    return welch, dict(weights=o["weights"], acquisition=o["acquisition"], period=period, se=o["se"]), n_segments


def settings_record(welch: dict, fit: dict) -> dict:
    """``route_settings``' ``welch`` and ``fit`` as the results record them: ``fs_hz``,
    ``nperseg``, ``noverlap``, ``nfft`` (``nperseg`` when not given), ``window`` (a list for a
    tuple), ``fmax_hz``, ``weights``, ``acquisition``, ``period_s``, ``se``."""
    window = welch["window"]
    return dict(
        fs_hz=welch["fs"],
        nperseg=welch["nperseg"],
        noverlap=welch["noverlap"],
        nfft=welch["nperseg"] if welch["nfft"] is None else welch["nfft"],
        window=list(window) if isinstance(window, tuple) else window,
        fmax_hz=welch["fmax"],
        weights=fit["weights"],
        acquisition=fit["acquisition"],
        period_s=fit["period"],
        se=fit["se"],
    )


def analyse(rec: dict, *, fs: float, lines: bool = False, **options):
    """Estimate ``Z`` (``estimate``, with its error model) and fit ``M, B, K``
    (``fit_impedance``) for a loaded recording sampled at ``fs`` [Hz], with the Welch route's
    ``options`` (``route_settings``; the defaults: segments that follow the record, a fitted
    delay, spectral SEs); returns ``(Estimate, ImpedanceFit)``. With ``lines``, only the bins
    that hold the perturbation on both axes are fitted (``input_bins``). Needs float64
    switched on; ``window`` must be a name or tuple."""
    from ..._estimation.fit import fit_impedance

    welch, fit, _ = route_settings(rec["x"].shape[0], fs=fs, **options)
    # Each is one compiled program per record shape and settings, shared with any other caller
    # of the same shapes (a wrapping jit would compile the pair again for every call).
    est = estimate(rec["f_delta"], rec["x"], rec["fh"], **welch, errors=True)
    if lines:
        holds, _ = input_bins(rec["f_delta"], welch)
        if holds.sum() < 3:
            raise ValueError(f"--lines: only {int(holds.sum())} bins hold the perturbation on both axes; need 3")
        fit = dict(fit, weights=holds.astype(float))
    return est, fit_impedance(est, **fit)


LINE_POWER = 1e-3  # of the largest bin's: a bin below this holds none of the perturbation's power
SPARSE_SHARE = 0.5  # a perturbation in fewer of the band's bins than this share: lines, not a spectrum


def input_bins(f_delta, welch: dict) -> tuple[np.ndarray, float]:
    """``(holds, share)``: which of the estimate's bins (``0 < f <= fmax``) hold the perturbation
    on both axes (its power above ``LINE_POWER`` of the largest bin's, per axis), and their
    share of the band's bins. A broadband perturbation fills the band; a multisine's lines
    fill a few bins (``SPARSE_SHARE``)."""
    import scipy.signal

    f_delta = np.asarray(f_delta, dtype=float)
    nfft = welch["nperseg"] if welch.get("nfft") is None else welch["nfft"]
    window = welch.get("window", "hann")
    kw = dict(fs=welch["fs"], window=window, nperseg=welch["nperseg"], noverlap=welch["noverlap"], nfft=nfft)
    freqs, p = scipy.signal.welch(f_delta, axis=0, detrend=False, **kw)
    band = (freqs > 0) & (freqs <= welch["fmax"])
    p = p[band]
    holds = np.all(p > LINE_POWER * p.max(axis=0), axis=1)
    return holds, float(holds.mean())


PARAMETERS = (("mass", "kg"), ("damping", "N s/m"), ("stiffness", "N/m"))


def intervals(fit, level: float = 0.95) -> dict:
    """``{name: {"low", "high"}}`` two-sided ``level`` intervals of ``mass``, ``damping``,
    ``stiffness`` (``(2, 2)`` each) and ``delay`` (``ImpedanceFit.interval``)."""
    out = {}
    for name in (*(n for n, _ in PARAMETERS), "delay"):
        low, high = fit.interval(name, level)
        out[name] = {"low": low, "high": high}
    return out


NOISY_VAF = 90.0  # [%] with no lack of fit, a VAF below this: the estimate's noise is much of Z


def verdict(fit, *, share: float | None = None, lines: bool = False) -> tuple[str, str]:
    """Whether the fitted model describes the estimate of ``Z``, reading the lack-of-fit test,
    the VAF and where the perturbation has its power (``share``: of the band's bins that hold
    it on both axes, ``input_bins``) together: ``(headline, explanation)`` (the headline titles
    ``bode.png``).

    The lack-of-fit ratio compares the residuals with what the estimate's own noise predicts;
    VAF is the share of ``Z``'s variance the model accounts for. A passing test with a low VAF
    is no contradiction: the residual is noise, and the noise is most of ``Z``. But a
    perturbation in a few bins (a multisine's lines) leaves every other bin to the person's
    own force (below 2 Hz) and the sensors' noise: ``Z`` there is not the arm's, and a fit over
    every bin cannot tell (``lines``: only the bins that hold it were fitted)."""
    vaf = float(np.asarray(fit.vaf_overall))
    p = float(np.asarray(fit.lack_of_fit_p_overall))
    if share is not None and share < SPARSE_SHARE and not lines:
        return (
            f"the classical route cannot tell from these bins: the perturbation is in {share:.0%} of them",
            "its power sits in a few Welch bins (a multisine's lines); the bins between hold the person's own "
            "force (below 2 Hz) and the sensors' noise, not a response to the perturbation, so a fit over every bin "
            f"describes them (VAF {vaf:.1f} %): fit the bins that hold the lines (--lines), or use the model route "
            "(--model)",
        )
    where = f" (the {share:.0%} of the bins that hold the perturbation's lines)" if lines and share is not None else ""
    if np.isnan(p):
        return "no lack-of-fit test", "without the estimate's error model, noise and misfit cannot be told apart"
    if p < LACK_OF_FIT_ALPHA:
        return (
            f"the model does not describe Z{where} (lack of fit, p = {p:.2g})",
            "the residuals exceed the estimate's noise, so M, B, K and their intervals describe a wrong model",
        )
    if vaf >= NOISY_VAF:
        return (
            f"the model describes Z{where} within the estimate's noise (no lack of fit, p = {p:.2g})",
            f"it accounts for {vaf:.1f} % of Z's variance, and the rest is what the estimate's noise predicts",
        )
    return (
        f"no evidence against the model at this noise{where} (no lack of fit, p = {p:.2g}), but a noisy estimate",
        f"what the model leaves of Z (VAF {vaf:.1f} %) is what the estimate's own noise predicts: the noise, "
        "the person's own force below 2 Hz included, is much of Z; the intervals are wide (a longer record or a "
        "larger perturbation narrows them)",
    )


def write_results(
    out_dir, est, fit, *, settings: dict, record: dict, warnings: list[str], share=None, lines: bool = False
) -> list[pathlib.Path]:
    """Write ``estimate.json``, ``estimate.npz``, ``bode.png`` and ``coherence.png`` under
    ``out_dir`` (each atomically); returns their paths. ``share`` and ``lines`` are the
    ``verdict``'s (where the perturbation has its power; only its bins fitted)."""
    out_dir = pathlib.Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    acq = dict(acquisition=settings.get("acquisition", "plain"), period=settings.get("period_s", 1e-3))
    z_fit = fit.impedance(est.f, **acq)
    result = {
        "settings": settings,
        "record": record,
        "units": {
            "f": "Hz",
            "mass": "kg",
            "damping": "N s/m",
            "stiffness": "N/m",
            "delay": "s",
            "Z": "N/m",
            "vaf": "%",
        },
        "convention": (
            "Z = T R^-1 [N/m], force applied to the hand per hand displacement, indexed [output, input] "
            "(row: force axis, column: displacement axis), axes of the recording's frame; "
            "Z(f) = K - w^2 M + j w B, w = 2 pi f, in the acquisition's model of the record "
            "(docs/estimation.md); a 95% interval is value +- t95 * se, t95 = t_0.975(dof), given as interval_95"
        ),
        **{k: np.asarray(getattr(fit, k)) for k in ("mass", "mass_se", "damping", "damping_se")},
        **{k: np.asarray(getattr(fit, k)) for k in ("stiffness", "stiffness_se", "dof")},
        "t95": _t95(np.asarray(fit.dof)),
        "interval_95": intervals(fit),
        "delay": {"value": np.asarray(fit.delay), "se": np.asarray(fit.delay_se), "dof": np.asarray(fit.delay_dof)},
        "lack_of_fit": {
            "ratio": np.asarray(fit.lack_of_fit_overall),
            "p": np.asarray(fit.lack_of_fit_p_overall),
            "per_element_ratio": np.asarray(fit.lack_of_fit),
            "per_element_p": np.asarray(fit.lack_of_fit_p),
        },
        "vaf": {"overall": np.asarray(fit.vaf_overall), "per_element": np.asarray(fit.vaf)},
        "coherence": coherence_summary(est),
        "perturbation_bins_share": share,
        "verdict": dict(zip(("headline", "explanation"), verdict(fit, share=share, lines=lines), strict=True)),
        "warnings": list(warnings),
    }
    est_arrays = {k: v for k, v in est._asdict().items() if k != "error"}
    errors = {f"error_{k}": v for k, v in est.error._asdict().items()} if est.error is not None else {}
    json_path = out_dir / "estimate.json"
    atomic_write_json(json_path, result)
    return [
        json_path,
        atomic_write_npz(out_dir / "estimate.npz", **est_arrays, **errors, Z_fit=z_fit),
        save_figure(
            bode_figure(est.f, est.Z, z_fit, title=_bode_title(fit, acq["acquisition"], share, lines)),
            out_dir / "bode.png",
        ),
        save_figure(coherence_figure(est), out_dir / "coherence.png"),
    ]


def _bode_title(fit, acquisition: str, share=None, lines: bool = False) -> str:
    """``bode.png``'s title: what is drawn, then the VAF and the ``verdict``'s headline."""
    vaf = float(np.asarray(fit.vaf_overall))
    return (
        f"Z: Welch estimate and fitted model (acquisition {acquisition!r}); the estimate's phase within 180 deg "
        f"of the model's\nVAF {vaf:.1f} %: {verdict(fit, share=share, lines=lines)[0]}"
    )


def _t95(dof):
    import scipy.stats

    return scipy.stats.t.ppf(0.975, np.where(np.isfinite(dof), dof, np.inf))
