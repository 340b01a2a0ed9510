"""Study tools on top of the general simulator: checked result records and run folders,
statistics, tidy tables, figures, recordings, sweeps, many-host runs and gradient tuning.
Files live here and above; nothing below this layer reads or writes one.

The modules, one job each: ``engine`` (the one engine of every study: ``engine.run`` owns the
run folder, the lock, resume, the perturbation cache, the batch loop and progress; a study is
a specification), ``runfolder`` (the run folder as a handle, ``StudyRun``: ``run.json``,
refusals, the lock, the trial records), ``console`` (what a study says on the terminal: the
progress bar, the finishing steps), ``cli`` (what the scripts share: the parser, one-line
errors; no JAX), ``points`` (the one trial description: a sweep's settings and the typed
``Point``), ``grids`` (a run's points from grids, TOML and ``--set``), ``config`` (TOML
configs, read into the same schema), ``metrics`` (the saved
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
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # what a type checker reads: every name from its module (none loads here)
    from .engine import Perturbations as Perturbations
    from .engine import SimulationSpec as SimulationSpec
    from .engine import Spec as Spec
    from .engine import run as run
    from .figures import save_figure as save_figure
    from .grids import expand as expand
    from .grids import parse_set as parse_set
    from .grids import read_toml as read_toml
    from .identify_recording import IdentifyConfigError as IdentifyConfigError
    from .identify_recording import read_identify_config as read_identify_config
    from .points import POINT_DEFAULTS as POINT_DEFAULTS
    from .points import Point as Point
    from .points import build_trial as build_trial
    from .points import known_settings as known_settings
    from .points import normalize_point as normalize_point
    from .recording import load_recording as load_recording
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
    "Point": "points",
    "known_settings": "points",
    "expand": "grids",
    "normalize_point": "points",
    "build_trial": "points",
    "parse_set": "grids",
    "read_toml": "grids",
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


if not TYPE_CHECKING:  # a type checker reads the imports above, and flags a name they lack

    def __getattr__(name: str):
        module = _EXPORTS.get(name)
        if module is None:
            raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(f".{module}", __name__), name)
        globals()[name] = value
        return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))
