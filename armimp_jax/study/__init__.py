"""Study tools on top of the general simulator: checked result records and run folders,
statistics, tidy tables, figures, recordings, sweeps, many-host runs and gradient tuning.
Files live here and above; nothing below this layer reads or writes one.

Five folders by purpose, in an order where none imports from a later one: ``runs`` (engine,
runfolder, results, seeds, distributed, console, cli), ``schema`` (points, grids, config),
``sweep`` (sweep, tables, figures, metrics, stats, threshold, coverage), ``recording`` (the lab's
recordings, both routes, calibration files, a movement's day) and ``design`` (experiment design's
files and check, the tuner). The modules, one job each: ``engine`` (the one engine of every
study: ``engine.run`` owns the run folder, the lock, resume, the perturbation cache, the batch
loop and progress; a study is a specification), ``runfolder`` (the run folder as a handle, ``StudyRun``: ``run.json``,
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
``armimp_jax.study.runs.distributed``'s option helpers and ``cli`` stay importable without JAX).
"""

from __future__ import annotations

import importlib
import importlib.abc
import sys
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # what a type checker reads: every name from its module (none loads here)
    from .recording.identify_recording import IdentifyConfigError as IdentifyConfigError
    from .recording.identify_recording import read_identify_config as read_identify_config
    from .recording.recording import load_recording as load_recording
    from .runs.engine import Perturbations as Perturbations
    from .runs.engine import SimulationSpec as SimulationSpec
    from .runs.engine import Spec as Spec
    from .runs.engine import run as run
    from .runs.results import ResultsError as ResultsError
    from .runs.results import atomic_write_json as atomic_write_json
    from .runs.results import load_record as load_record
    from .runs.results import read_json as read_json
    from .runs.results import save_record as save_record
    from .runs.results import settings_key as settings_key
    from .runs.results import stamped as stamped
    from .runs.runfolder import RunLock as RunLock
    from .runs.runfolder import StudyRun as StudyRun
    from .runs.seeds import perturbation_key as perturbation_key
    from .schema.config import build_trial as build_trial
    from .schema.grids import expand as expand
    from .schema.grids import parse_set as parse_set
    from .schema.grids import read_toml as read_toml
    from .schema.points import POINT_DEFAULTS as POINT_DEFAULTS
    from .schema.points import Point as Point
    from .schema.points import known_settings as known_settings
    from .schema.points import normalize_point as normalize_point
    from .sweep.figures import save_figure as save_figure
    from .sweep.stats import CI_LEVEL as CI_LEVEL
    from .sweep.stats import MeanCI as MeanCI
    from .sweep.stats import bootstrap_crossing as bootstrap_crossing
    from .sweep.stats import first_crossing as first_crossing
    from .sweep.stats import mean_ci as mean_ci
    from .sweep.stats import seed_stats as seed_stats
    from .sweep.sweep import SweepSettings as SweepSettings
    from .sweep.sweep import load_summary as load_summary
    from .sweep.sweep import load_sweep as load_sweep
    from .sweep.sweep import run_sweep as run_sweep
    from .sweep.tables import read_table as read_table
    from .sweep.tables import write_table as write_table

_EXPORTS = {
    "CI_LEVEL": "sweep.stats",
    "MeanCI": "sweep.stats",
    "mean_ci": "sweep.stats",
    "seed_stats": "sweep.stats",
    "first_crossing": "sweep.stats",
    "bootstrap_crossing": "sweep.stats",
    "StudyRun": "runs.runfolder",
    "RunLock": "runs.runfolder",
    "ResultsError": "runs.results",
    "atomic_write_json": "runs.results",
    "read_json": "runs.results",
    "stamped": "runs.results",
    "save_record": "runs.results",
    "load_record": "runs.results",
    "settings_key": "runs.results",
    "perturbation_key": "runs.seeds",
    "read_table": "sweep.tables",
    "write_table": "sweep.tables",
    "save_figure": "sweep.figures",
    "load_recording": "recording.recording",
    "IdentifyConfigError": "recording.identify_recording",
    "read_identify_config": "recording.identify_recording",
    "POINT_DEFAULTS": "schema.points",
    "Point": "schema.points",
    "known_settings": "schema.points",
    "expand": "schema.grids",
    "normalize_point": "schema.points",
    "build_trial": "schema.config",
    "parse_set": "schema.grids",
    "read_toml": "schema.grids",
    "SweepSettings": "sweep.sweep",
    "run_sweep": "sweep.sweep",
    "run": "runs.engine",
    "Spec": "runs.engine",
    "SimulationSpec": "runs.engine",
    "Perturbations": "runs.engine",
    "load_sweep": "sweep.sweep",
    "load_summary": "sweep.sweep",
}
__all__ = sorted(_EXPORTS)
# the modules that moved into folders (3.3.0), by their old names: a user's import is told where
_MOVED = {
    **dict.fromkeys(("engine", "runfolder", "results", "seeds", "distributed", "console", "cli"), "runs"),
    **dict.fromkeys(("points", "grids", "config"), "schema"),
    **dict.fromkeys(("tables", "figures", "metrics", "stats", "threshold", "coverage"), "sweep"),
    **dict.fromkeys(
        (
            "estimate_recording",
            "identify_recording",
            "identify_pool",
            "recording_figures",
            "recording_report",
            "calibration_files",
            "movement_day",
            "movement_figures",
        ),
        "recording",
    ),
    **dict.fromkeys(("design_experiment", "design_check", "design_report", "tuning"), "design"),
}


def _folder_getattr(package: str, module: str):
    """The ``__getattr__`` of a folder named as 3.2.0's module ``module`` was (``sweep``,
    ``recording``): a name that module held is now in ``{package}.{module}``, and says so."""

    def __getattr__(name: str):
        if name.startswith("__"):
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        raise AttributeError(
            f"module {package!r} (a folder since 3.3.0) has no attribute {name!r}: import it from its module, "
            f"{package}.{module}, or another of the folder's"
        )

    return __getattr__


class _Moved(importlib.abc.MetaPathFinder):
    """Tells ``import armimp_jax.study.points`` (and ``from armimp_jax.study import points``) where
    a module that moved into its folder went; other names it leaves to the other finders."""

    def find_spec(self, fullname, path=None, target=None):
        head, _, name = fullname.rpartition(".")
        if head == __name__ and name in _MOVED:
            raise ImportError(f"{fullname} moved to {__name__}.{_MOVED[name]}.{name}")
        return None


if not any(type(f).__name__ == "_Moved" for f in sys.meta_path):
    sys.meta_path.append(_Moved())


if not TYPE_CHECKING:  # a type checker reads the imports above, and flags a name they lack

    def __getattr__(name: str):
        module = _EXPORTS.get(name)
        if name in _MOVED:
            raise AttributeError(f"{__name__}.{name} moved to {__name__}.{_MOVED[name]}.{name}")
        if module is None:
            raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(f".{module}", __name__), name)
        globals()[name] = value
        return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))
