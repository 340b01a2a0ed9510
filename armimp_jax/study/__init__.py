"""Study tools on top of the general simulator: checked result records and run folders,
statistics, tidy tables, figures, recordings, sweeps, many-host runs and gradient tuning.
Files live here and above; nothing below this layer reads or writes one.

The modules, one job each: ``engine`` (the one engine of every study: ``engine.run`` owns the
run folder, the lock, resume, the perturbation cache, the batch loop and progress; a study is
a specification), ``runfolder`` (the run folder as a handle, ``StudyRun``: ``run.json``,
refusals, the lock, the trial records), ``console`` (what a study says on the terminal: the
progress bar, the finishing steps), ``cli`` (what the scripts share: the parser, one-line
errors; no JAX), ``points`` (the one trial description: a sweep's settings, grids, TOML and
``--set``), ``config`` (TOML configs, read into the same schema), ``metrics`` (the saved
estimate fields, ``trial_metrics``), ``results`` (keys, checked records, atomic strict-JSON
and npz writes), ``stats`` (``mean_ci``, the bootstrap and bootstrap thresholds), ``seeds``
(common random numbers), ``tables`` (pandas tables, CSV and Parquet), ``figures``
(``save_figure``), ``sweep`` (the sweep's specification and ``run_sweep``), ``threshold``
(the friction threshold: a sweep, its analysis, figure and report), ``coverage`` (repeated
recordings identified: the coverage and efficiency studies' specification), ``distributed``
(many processes), ``recording`` (measured data in), ``estimate_recording`` (the Welch route
for measured data), ``recording_figures`` and ``recording_report`` (both routes' figures and
text), ``identify_recording`` (the model route for measured data: its config, ``identify``,
its results on disk), ``design_experiment`` (experiment design's config and its files),
``design_check`` (the record a design is written at, its numbers there, its Monte Carlo
check), ``movement_day`` and ``movement_figures`` (a lab's day for a movement: its config, the
ensemble, the classical route's table and figures) and ``tuning`` (the tuner, and its state on
disk).

The names below (one list, ``_EXPORTS``) are imported on first use (so
``armimp_jax.study.distributed``'s option helpers and ``cli`` stay importable without JAX).
"""

from __future__ import annotations

import importlib

_EXPORTS = {
    "CI_LEVEL": "stats",
    "MeanCI": "stats",
    "mean_ci": "stats",
    "seed_stats": "stats",
    "first_crossing": "stats",
    "bootstrap_crossing": "stats",
    "StudyRun": "runfolder",
    "RunLock": "runfolder",
    "ResultsError": "results",
    "atomic_write_json": "results",
    "read_json": "results",
    "stamped": "results",
    "save_record": "results",
    "load_record": "results",
    "settings_key": "results",
    "perturbation_key": "seeds",
    "read_table": "tables",
    "write_table": "tables",
    "save_figure": "figures",
    "load_recording": "recording",
    "IdentifyConfigError": "identify_recording",
    "read_identify_config": "identify_recording",
    "POINT_DEFAULTS": "points",
    "known_settings": "points",
    "expand": "points",
    "normalize_point": "points",
    "build_trial": "points",
    "parse_set": "points",
    "read_toml": "points",
    "SweepSettings": "sweep",
    "run_sweep": "sweep",
    "run": "engine",
    "Spec": "engine",
    "SimulationSpec": "engine",
    "Perturbations": "engine",
    "load_sweep": "sweep",
    "load_summary": "sweep",
}
__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{module}", __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))
