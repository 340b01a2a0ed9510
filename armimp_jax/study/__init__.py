"""Study tools on top of the general simulator: checked result records and run folders,
statistics, tidy tables, figures, recordings, sweeps, many-host runs and gradient tuning.
Files live here and above; nothing below this layer reads or writes one.

The modules, one job each: ``points`` (a sweep's settings, grids, TOML and ``--set``),
``runfolder`` (one run per folder: ``run.json``, refusals, the lock, trial status),
``engine`` (the one run-trials engine: run folder, batches, progress, resume), ``metrics``
(the saved estimate fields, ``trial_metrics``), ``results`` (keys, checked records, atomic
strict-JSON and npz writes), ``stats`` (``mean_ci``, the bootstrap and bootstrap
thresholds), ``seeds`` (common random numbers), ``tables`` (pandas tables, CSV and
Parquet), ``figures`` (``save_figure``), ``sweep`` (the sweep's specification and
``run_sweep``), ``distributed`` (many processes), ``recording`` (measured data in),
``estimate_recording`` (the Welch route for measured data), ``recording_figures`` and
``recording_report`` (both routes' figures and text), ``config`` (the one trial schema:
TOML configs and sweep points), ``identify_recording`` (the model route for measured data:
its config, ``identify``, its results on disk), ``design_experiment`` (experiment design's
config and its files), ``design_check`` (the design's Monte Carlo check: its record, its
signal, the spread of ``identify``) and ``tune``.

The names below are imported on first use (so ``armimp_jax.study.distributed``'s option
helpers stay importable without JAX).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

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


if TYPE_CHECKING:
    from .figures import save_figure as save_figure
    from .identify_recording import IdentifyConfigError as IdentifyConfigError
    from .identify_recording import read_identify_config as read_identify_config
    from .points import POINT_DEFAULTS as POINT_DEFAULTS
    from .points import build_trial as build_trial
    from .points import expand as expand
    from .points import known_settings as known_settings
    from .points import normalize_point as normalize_point
    from .points import parse_set as parse_set
    from .points import read_toml as read_toml
    from .results import ResultsError as ResultsError
    from .results import atomic_write_json as atomic_write_json
    from .results import load_record as load_record
    from .results import read_json as read_json
    from .results import save_record as save_record
    from .results import settings_key as settings_key
    from .results import stamped as stamped
    from .runfolder import RunLock as RunLock
    from .runfolder import StudyRun as StudyRun
    from .seeds import perturbation_key as perturbation_key
    from .stats import CI_LEVEL as CI_LEVEL
    from .stats import MeanCI as MeanCI
    from .stats import bootstrap_crossing as bootstrap_crossing
    from .stats import first_crossing as first_crossing
    from .stats import mean_ci as mean_ci
    from .stats import seed_stats as seed_stats
    from .sweep import SweepSettings as SweepSettings
    from .sweep import load_summary as load_summary
    from .sweep import load_sweep as load_sweep
    from .sweep import run_sweep as run_sweep
    from .tables import read_table as read_table
    from .tables import write_table as write_table
