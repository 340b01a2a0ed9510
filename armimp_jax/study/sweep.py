"""General sweeps: a grid (or a list of points) over any settings of a trial, times seeds.

A *point* is a flat dict of JSON values that fixes one trial apart from its seed
(``POINT_DEFAULTS`` lists every setting with its default and unit): the controller, the
LuGre friction (a Coulomb torque ``tau_c`` with the stiction given as a ratio), the arm
(paper location 1-4 or a user's matrices), the perturbation (level or peak, record
length), the sensors, the acquisition, IMBIC's ``mhat`` and the Welch settings.
``normalize_point`` resolves every default into a number, so equal trials give equal
points (and keys). ``expand`` turns a grid of value lists and/or a list of points into
the normalized, de-duplicated points of a run; ``read_toml`` and ``parse_set`` read them
from a TOML file and ``--set NAME=V1,V2`` options.

``run_sweep`` runs every ``(point, seed)`` that has no valid record in the output folder
(batched by static structure, sharded over the devices, in chunks for progress), saves
one checked record per trial (``armimp_jax.study.results``), then writes the tidy table
``trials.csv`` (one row per trial), ``summary.csv``/``summary.json`` (per point over
seeds: mean, standard deviation, 95% t-interval, count of diverged trials, which are left
out of every statistic) and a figure of ``phi_T`` against the swept quantity. The
integrity rules are those of ``docs/results.md``; ``docs/sweeps.md`` describes the files.

Seeds: trial seed ``s`` draws its perturbation from ``fold_in(PRNGKey(base_seed), s)``
(every point sees the same signal shape for the same seed: common random numbers) and
its sensor noise, if any, from ``fold_in`` of that key with 1.
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import io
import itertools
import json
import math
import pathlib
import sys
import time
import tomllib
import warnings
from collections.abc import Callable, Iterable, Mapping
from typing import Any

import jax
import numpy as np
from scipy import stats

from .._batch import Welch, assess_batch, check_numerics, make_mesh, simulate_batch
from .._estimation.fit import fit_impedance
from .._model.arm import Arm
from .._model.control import IMBIC, PD
from .._model.friction import LuGre
from .._model.perturbation import perturbation
from .._model.sensors import Sensors
from .._simulate import Trial, make_trial, stack_trials
from .._solver.numerics import METHODS, SWEEP_NUMERICS, Numerics
from . import distributed
from .results import (
    ResultsError,
    RunLock,
    atomic_write_json,
    atomic_write_text,
    describe_difference,
    load_record,
    read_json,
    save_record,
    settings_key,
    stamped,
    to_jsonable,
)

RUN_FORMAT = 1  # layout of a sweep's run.json
CI_LEVEL = 0.95  # two-sided level of every interval

# Every setting of a point, its default and its unit. ``None`` defaults are resolved by
# ``normalize_point`` (the peak from the perturbation level, the overlap from the segment).
POINT_DEFAULTS: dict[str, Any] = dict(
    controller="pd",  # "pd" | "imbic"
    tau_c=0.0,  # Coulomb torque [N m], both joints
    stiction_ratio=1.5,  # tau_s / tau_c [-], >= 1
    sigma0=1e5,  # bristle stiffness [N m/rad]
    sigma1=math.sqrt(1e5),  # bristle damping [N m s/rad]
    sigma2=0.5,  # viscous friction [N m s/rad]
    v_s=1e-3,  # Stribeck velocity [rad/s]
    arm=1,  # paper location 1-4, or {"mass", "damping", "stiffness": 2x2, "endpoint": (2,)}
    perturbation_level=1,  # paper level 1-3 (None when a peak is given)
    peak=None,  # per-axis peak |F_Delta| [N], (2,); default: the level's
    seconds=50.0,  # record length [s]
    force_noise=0.0,  # force-sensor noise sd [N]
    encoder_counts=None,  # encoder resolution [counts/rev]; None: exact angles
    velocity_noise=0.0,  # joint-rate noise sd [rad/s]
    acquisition="instant",  # "instant" | "interval_mean"
    mhat=0.25,  # IMBIC Mhat, times the identity [kg] (None for PD)
    nperseg=8192,  # Welch segment [samples]
    noverlap=None,  # Welch overlap [samples]; default 3/4 of nperseg
    fmax=15.0,  # highest frequency estimated [Hz]
    window="hann",  # a scipy.signal.get_window name (or [name, param])
    nfft=None,  # FFT length [samples]; None: nperseg
)
POINT_UNITS = dict(
    tau_c="N m",
    stiction_ratio="-",
    sigma0="N m/rad",
    sigma1="N m s/rad",
    sigma2="N m s/rad",
    v_s="rad/s",
    peak="N",
    seconds="s",
    force_noise="N",
    encoder_counts="counts/rev",
    velocity_noise="rad/s",
    mhat="kg",
    nperseg="samples",
    noverlap="samples",
    fmax="Hz",
    nfft="samples",
)
_ELEMENTS = ("11", "12", "21", "22")  # (2, 2) arrays as columns, [output, input], row-major
FIT_COLUMNS = tuple(f"{p}_{e}{se}" for p in ("M", "B", "K") for se in ("", "_se") for e in _ELEMENTS) + tuple(
    f"vaf_{e}" for e in _ELEMENTS
)
COH_COLUMNS = tuple(f"coh_{c}_{s}" for c in ("x1", "x2", "fh1", "fh2") for s in ("min", "median"))
# per-trial numbers: the statistics of summary.csv are taken over each of these
METRIC_COLUMNS = (
    ("phi_T",)
    + tuple(f"phi_{e}" for e in _ELEMENTS)
    + ("rel_error", "coh_min")
    + COH_COLUMNS
    + ("input_coherence_max",)
    + FIT_COLUMNS
    + ("vaf_overall",)
)
ESTIMATE_FIELDS = ("f", "Z", "coh_multiple_x", "coh_partial_x", "coh_multiple_fh", "coh_partial_fh", "coh_inputs")


# --- points ---------------------------------------------------------------------------------


def _number(name: str, value, *, minimum: float | None = None, exclusive: bool = False, integer: bool = False):
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ValueError(f"{name} must be a finite number, got {value!r}")
    if integer and int(value) != value:
        raise ValueError(f"{name} must be an integer, got {value!r}")
    if minimum is not None and (value <= minimum if exclusive else value < minimum):
        raise ValueError(f"{name} must be {'>' if exclusive else '>='} {minimum:g}, got {value!r}")
    return int(value) if integer else float(value)


def _matrix(name: str, value, shape) -> list:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"arm {name} must be numbers of shape {shape}, got {value!r}") from None
    if arr.shape != shape or not np.all(np.isfinite(arr)):
        raise ValueError(f"arm {name} must be finite numbers of shape {shape}, got {value!r}")
    return arr.tolist()


def _arm_setting(value):
    from ..presets._paper import LOCATIONS

    if isinstance(value, Mapping):
        need = {"mass", "damping", "stiffness", "endpoint"}
        if set(value) != need:
            raise ValueError(f"a user arm needs exactly the keys {', '.join(sorted(need))}; got {', '.join(value)}")
        shapes = dict(mass=(2, 2), damping=(2, 2), stiffness=(2, 2), endpoint=(2,))
        arm = {k: _matrix(k, value[k], shapes[k]) for k in sorted(need)}
        Arm(**arm)  # refuses a mass matrix that is not positive definite, with a one-line message
        return arm
    if isinstance(value, bool) or value not in LOCATIONS:
        raise ValueError(
            f"arm must be a paper location ({', '.join(map(str, LOCATIONS))}) or a user arm, got {value!r}"
        )
    return int(value)


def normalize_point(raw: Mapping) -> dict:
    """The canonical form of a point: every setting of ``POINT_DEFAULTS``, in that order,
    resolved to plain JSON values (defaults filled in, numbers as floats, the peak from the
    perturbation level, the overlap from the segment, ``mhat`` ``None`` for PD). Raises
    ``ValueError`` (one line) for an unknown setting or a value that cannot run."""
    from ..presets._paper import PERTURBATION_LEVELS, perturbation_peak

    unknown = [k for k in raw if k not in POINT_DEFAULTS]
    if unknown:
        raise ValueError(f"unknown setting(s) {', '.join(map(repr, unknown))}; known: {', '.join(POINT_DEFAULTS)}")
    p = dict(POINT_DEFAULTS) | dict(raw)
    out: dict[str, Any] = {}
    if p["controller"] not in ("pd", "imbic"):
        raise ValueError(f"controller must be 'pd' or 'imbic', got {p['controller']!r}")
    out["controller"] = p["controller"]
    out["tau_c"] = _number("tau_c [N m]", p["tau_c"], minimum=0.0)
    out["stiction_ratio"] = _number("stiction_ratio (tau_s / tau_c)", p["stiction_ratio"], minimum=1.0)
    for name in ("sigma0", "sigma1", "sigma2"):
        out[name] = _number(f"{name} [{POINT_UNITS[name]}]", p[name], minimum=0.0)
    out["v_s"] = _number("v_s [rad/s]", p["v_s"], minimum=0.0, exclusive=True)
    out["arm"] = _arm_setting(p["arm"])
    if raw.get("peak") is not None:
        peak = p["peak"]
        peak = [peak, peak] if isinstance(peak, (int, float)) and not isinstance(peak, bool) else peak
        if not isinstance(peak, (list, tuple)) or len(peak) != 2:
            raise ValueError(f"peak must be a number or two numbers [N], got {p['peak']!r}")
        out["peak"] = [_number("peak [N]", v, minimum=0.0, exclusive=True) for v in peak]
        level = raw.get("perturbation_level")
        # a normalized point names both (level and its peak): accept that, refuse a mismatch
        if level is not None and (level not in PERTURBATION_LEVELS or perturbation_peak(level).tolist() != out["peak"]):
            raise ValueError(f"give perturbation_level or peak, not both (got level {level!r} and peak {peak!r})")
        out["perturbation_level"] = level
        out["peak"] = out.pop("peak")
    else:
        level = p["perturbation_level"]
        if isinstance(level, bool) or level not in PERTURBATION_LEVELS:
            raise ValueError(
                f"perturbation_level must be one of {', '.join(map(str, PERTURBATION_LEVELS))}, got {level!r}"
            )
        out["perturbation_level"] = int(level)
        out["peak"] = perturbation_peak(int(level)).tolist()
    out["seconds"] = _number("seconds", p["seconds"], minimum=0.0, exclusive=True)
    out["force_noise"] = _number("force_noise [N]", p["force_noise"], minimum=0.0)
    out["encoder_counts"] = (
        None if p["encoder_counts"] is None else _number("encoder_counts", p["encoder_counts"], minimum=1.0)
    )
    out["velocity_noise"] = _number("velocity_noise [rad/s]", p["velocity_noise"], minimum=0.0)
    if p["acquisition"] not in ("instant", "interval_mean"):
        raise ValueError(f"acquisition must be 'instant' or 'interval_mean', got {p['acquisition']!r}")
    out["acquisition"] = p["acquisition"]
    out["mhat"] = None if out["controller"] == "pd" else _number("mhat [kg]", p["mhat"], minimum=0.0, exclusive=True)
    out["nperseg"] = _number("nperseg", p["nperseg"], minimum=2, integer=True)
    noverlap = 3 * out["nperseg"] // 4 if p["noverlap"] is None else p["noverlap"]
    out["noverlap"] = _number("noverlap", noverlap, minimum=0, integer=True)
    out["fmax"] = _number("fmax [Hz]", p["fmax"], minimum=0.0, exclusive=True)
    window = p["window"]
    if not (isinstance(window, str) or (isinstance(window, (list, tuple)) and window and isinstance(window[0], str))):
        raise ValueError(f"window must be a name or [name, parameter, ...], got {window!r}")
    out["window"] = window if isinstance(window, str) else list(window)
    out["nfft"] = None if p["nfft"] is None else _number("nfft", p["nfft"], minimum=2, integer=True)
    try:
        point_welch(out).check(n_samples(out))
    except ValueError as err:
        raise ValueError(f"seconds={out['seconds']:g}, nperseg={out['nperseg']}: {err}") from None
    return out


def n_samples(point: Mapping) -> int:
    """Record length of a point [samples at 1 kHz]."""
    return int(round(point["seconds"] * 1000))


def point_welch(point: Mapping) -> Welch:
    """The ``Welch`` settings of a normalized point (hashable: a window list becomes a tuple)."""
    window = point["window"] if isinstance(point["window"], str) else tuple(point["window"])
    return Welch(point["nperseg"], point["noverlap"], point["fmax"], window=window, nfft=point["nfft"])


def point_arm(point: Mapping) -> Arm:
    """The ``Arm`` of a normalized point: a paper location's, or the user's."""
    from ..presets._paper import arm as paper_arm

    return paper_arm(point["arm"]) if isinstance(point["arm"], int) else Arm(**point["arm"])


def build_trial(point: Mapping) -> Trial:
    """The ``Trial`` of a normalized point (``make_trial`` on MIT-MANUS)."""
    ctrl = PD() if point["controller"] == "pd" else IMBIC(point["mhat"] * np.eye(2))
    arm = point_arm(point)
    friction = LuGre(
        point["tau_c"],
        point["tau_c"] * point["stiction_ratio"],
        sigma0=point["sigma0"],
        sigma1=point["sigma1"],
        sigma2=point["sigma2"],
        v_s=point["v_s"],
    )
    sensors = Sensors(point["force_noise"], point["encoder_counts"], point["velocity_noise"])
    return make_trial(ctrl, arm=arm, friction=friction, sensors=sensors, acquisition=point["acquisition"])


def static_group(point: Mapping) -> tuple:
    """What must agree within one compiled batch: controller type, acquisition, encoder
    on/off, record length and Welch settings."""
    return (
        point["controller"],
        point["acquisition"],
        point["encoder_counts"] is not None,
        n_samples(point),
        point_welch(point),
    )


def expand(grid: Mapping[str, Iterable] | None = None, points: Iterable[Mapping] | None = None) -> list[dict]:
    """The normalized points of a run: every entry of ``points`` (default one empty point)
    combined with the cartesian product of ``grid`` (setting -> list of values), de-duplicated
    in order (e.g. PD points that differ only in ``mhat``). A setting named both in a point
    and in the grid is refused."""
    grid = {k: list(v) if isinstance(v, (list, tuple)) else [v] for k, v in (grid or {}).items()}
    for name, values in grid.items():
        if not values:
            raise ValueError(f"grid setting {name!r} has no values")
    bases = [dict(p) for p in points] if points is not None else [{}]
    if not bases:
        raise ValueError("the list of points is empty")
    out, seen = [], set()
    for base in bases:
        both = sorted(set(base) & set(grid))
        if both:
            raise ValueError(f"setting(s) {', '.join(both)} given both in a point and in the grid")
        for combo in itertools.product(*grid.values()):
            point = normalize_point(base | dict(zip(grid, combo, strict=True)))
            key = json.dumps(point, sort_keys=True)
            if key not in seen:
                seen.add(key)
                out.append(point)
    return out


def _split_top(text: str) -> list[str]:
    parts, depth, start, quote = [], 0, 0, None
    for i, ch in enumerate(text):
        if quote:
            quote = None if ch == quote else quote
        elif ch in "\"'":
            quote = ch
        elif ch in "[{(":
            depth += 1
        elif ch in "]})":
            depth -= 1
        elif ch == "," and depth == 0:
            parts.append(text[start:i])
            start = i + 1
    parts.append(text[start:])
    return [p.strip() for p in parts]


def _value(text: str):
    if text in ("none", "None", "null"):
        return None
    try:
        return json.loads(text)
    except ValueError:
        return text  # a bare word: "pd", "hann", "interval_mean"


def parse_set(options: Iterable[str]) -> dict[str, list]:
    """Grid from ``--set`` options ``NAME=V1,V2,...``: values split at top-level commas, each
    read as JSON (``[3,3]``, ``{"mass": ...}``, ``null``/``none``) or else as a bare word.
    ``NAME=geom:A:B:N`` (N log-spaced values from A to B) and ``NAME=lin:A:B:N`` are ranges."""
    grid: dict[str, list] = {}
    for opt in options:
        name, sep, text = opt.partition("=")
        name = name.strip()
        if not sep or not name or not text.strip():
            raise ValueError(f"--set needs NAME=V1,V2,..., got {opt!r}")
        if name in grid:
            raise ValueError(f"--set {name} given twice")
        if text.startswith(("geom:", "lin:")):
            kind, *args = text.split(":")
            try:
                a, b, n = float(args[0]), float(args[1]), int(args[2])
            except (ValueError, IndexError):
                raise ValueError(f"--set {name}={text}: a range is {kind}:START:STOP:COUNT") from None
            if n < 1 or (kind == "geom" and not (a > 0 and b > 0)):
                raise ValueError(f"--set {name}={text}: need COUNT >= 1 (and START, STOP > 0 for geom)")
            grid[name] = (np.geomspace(a, b, n) if kind == "geom" else np.linspace(a, b, n)).tolist()
        else:
            grid[name] = [_value(v) for v in _split_top(text)]
    return grid


def read_toml(path) -> tuple[dict, list | None, dict]:
    """``(grid, points, options)`` from a TOML file: a ``[grid]`` table of settings (a list is
    swept, a single value fixed), an optional ``[[points]]`` array of tables, and an optional
    ``[run]`` table (``seeds``, ``base_seed``, ``method``, ``substeps``). One-line errors."""
    path = pathlib.Path(path)
    try:
        data = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise ValueError(f"{path}: no such file") from None
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as err:
        raise ValueError(f"{path}: not valid TOML ({' '.join(str(err).split())})") from None
    extra = sorted(set(data) - {"grid", "points", "run"})
    if extra:
        raise ValueError(f"{path}: unknown table(s) {', '.join(extra)}; allowed: grid, points, run")
    grid, points, run = data.get("grid", {}), data.get("points"), data.get("run", {})
    if not isinstance(grid, dict) or not isinstance(run, dict):
        raise ValueError(f"{path}: [grid] and [run] must be tables")
    if points is not None and not (isinstance(points, list) and all(isinstance(p, dict) for p in points)):
        raise ValueError(f"{path}: points must be an array of tables ([[points]])")
    bad = sorted(set(run) - {"seeds", "base_seed", "method", "substeps"})
    if bad:
        raise ValueError(
            f"{path}: unknown [run] option(s) {', '.join(bad)}; allowed: seeds, base_seed, method, substeps"
        )
    return grid, points, run


# --- run settings ---------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class SweepSettings:
    """Everything that fixes a sweep's numbers: its normalized ``points`` (``expand``), the
    number of ``seeds`` per point from ``base_seed``, and the integration ``method`` and
    ``substeps`` per 1 ms period (default ``SWEEP_NUMERICS``)."""

    points: tuple
    seeds: int = 3
    base_seed: int = 0
    method: str = SWEEP_NUMERICS.method
    substeps: int = SWEEP_NUMERICS.substeps

    def __post_init__(self):
        object.__setattr__(self, "points", tuple(normalize_point(p) for p in self.points))

    @property
    def numerics(self) -> Numerics:
        return Numerics(substeps=self.substeps, method=self.method)

    def validate(self) -> None:
        """Raise ``ValueError`` (one line) for settings that cannot run."""
        if not self.points:
            raise ValueError("a sweep needs at least one point")
        if isinstance(self.seeds, bool) or not isinstance(self.seeds, int) or self.seeds < 1:
            raise ValueError(f"seeds must be an integer >= 1, got {self.seeds!r}")
        if isinstance(self.base_seed, bool) or not isinstance(self.base_seed, int) or self.base_seed < 0:
            raise ValueError(f"base_seed must be an integer >= 0, got {self.base_seed!r}")
        if self.method not in METHODS:
            raise ValueError(f"method must be one of {', '.join(METHODS)}, got {self.method!r}")
        if isinstance(self.substeps, bool) or not isinstance(self.substeps, int) or self.substeps < 1:
            raise ValueError(f"substeps must be an integer >= 1, got {self.substeps!r}")

    def run_settings(self) -> dict:
        """As saved in ``run.json`` (package version included)."""
        return stamped(
            dict(points=list(self.points), seeds=self.seeds, base_seed=self.base_seed, numerics=self._numerics_dict())
        )

    def _numerics_dict(self) -> dict:
        return dict(method=self.method, substeps=self.substeps, kernel="fast")

    def trial_settings(self, point: Mapping, seed: int) -> dict:
        """Every value that changes one trial's numbers: its point, seed, base seed and numerics
        (the seed count, the other points and the batch size do not)."""
        return stamped(
            dict(point=dict(point), seed=int(seed), base_seed=self.base_seed, numerics=self._numerics_dict())
        )

    @classmethod
    def from_saved(cls, saved: Mapping, *, where: str = "run.json") -> SweepSettings:
        try:
            num = saved["numerics"]
            return cls(tuple(saved["points"]), saved["seeds"], saved["base_seed"], num["method"], num["substeps"])
        except (KeyError, TypeError, ValueError) as err:
            raise ResultsError(f"{where}: not the settings of a sweep ({err})") from None


def describe_run_difference(saved: SweepSettings, wanted: SweepSettings) -> str:
    """One line saying how two sweeps differ (the points compared one by one)."""
    a, b = saved.run_settings(), wanted.run_settings()
    pa, pb = a.pop("points"), b.pop("points")
    parts = [] if a == b else [describe_difference(a, b)]
    if len(pa) != len(pb):
        parts.append(f"{len(pa)} points (you asked {len(pb)})")
    for i, (x, y) in enumerate(zip(pa, pb, strict=False)):
        if x != y:
            parts.append(f"point {i}: {describe_difference(x, y, limit=3)}")
            break
    return ", ".join(parts) or "no difference"


def trial_id(settings: SweepSettings, point: Mapping, seed: int) -> str:
    """File name stem of a trial: a short hash of its point (stable across runs) and the seed."""
    return f"p{settings_key(dict(point=dict(point)))[:12]}-s{seed}"


def read_run(out) -> dict:
    """``run.json`` of the sweep in ``out``, checked (``ResultsError`` naming what is wrong)."""
    out = pathlib.Path(out)
    run_file = out / "run.json"
    if not run_file.exists():
        raise ResultsError(f"{out} holds no sweep (no run.json)")
    run = read_json(run_file)
    if not isinstance(run, dict) or run.get("kind") != "sweep" or run.get("format") != RUN_FORMAT:
        raise ResultsError(f"{run_file}: not a sweep's run.json (another study, or another armimp_jax)")
    if settings_key(run.get("settings", {})) != run.get("key"):
        raise ResultsError(f"{run_file}: its settings were edited after the run (key mismatch)")
    return run


def saved_settings(out) -> SweepSettings:
    """The settings of the sweep in ``out`` (to resume it)."""
    return SweepSettings.from_saved(read_run(out)["settings"], where=str(pathlib.Path(out) / "run.json"))


def prepare_output(out, settings: SweepSettings) -> None:
    """Create ``out`` and write ``run.json``, or check that the run there has ``settings``
    (a folder holding another sweep is refused in one line naming the differences)."""
    out = pathlib.Path(out)
    run_file = out / "run.json"
    try:
        (out / "trials").mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise ResultsError(f"output folder {out} is not writable: {err}") from None
    wanted = settings.run_settings()
    if run_file.exists():
        run = read_run(out)
        if run["key"] != settings_key(wanted):
            diff = describe_run_difference(SweepSettings.from_saved(run["settings"], where=str(run_file)), settings)
            raise ResultsError(
                f"{out} holds a sweep with {diff}: use another output folder (--out), or resume it (--resume {out})"
            )
        return
    atomic_write_json(run_file, dict(kind="sweep", format=RUN_FORMAT, settings=wanted, key=settings_key(wanted)))


def _warn_stderr(message: str) -> None:
    sys.stderr.write(f"warning: {message}\n")


def trial_status(settings: SweepSettings, out, *, warn: Callable[[str], None] = _warn_stderr):
    """``(records, todo)``: ``{(point index, seed): Record}`` of the trials whose record passes
    its check, and the ``(point index, seed)`` pairs still to run; every other existing
    record is named in a warning (it will be recomputed)."""
    out = pathlib.Path(out)
    records, todo = {}, []
    for i, point in enumerate(settings.points):
        for s in range(settings.seeds):
            path = out / "trials" / f"{trial_id(settings, point, s)}.npz"
            if path.exists():
                try:
                    records[i, s] = load_record(path, settings=settings.trial_settings(point, s))
                    continue
                except ResultsError as err:
                    warn(f"{err}; recomputing it")
            todo.append((i, s))
    return records, todo


# --- per-trial metrics ------------------------------------------------------------------------


def _cells(prefix: str, a) -> dict:
    a = np.asarray(a, dtype=float).reshape(-1)
    return {f"{prefix}_{e}": float(v) for e, v in zip(_ELEMENTS, a, strict=True)}


def trial_metrics(point: Mapping, outcome_i: Mapping, fit_i: Mapping) -> dict:
    """The scalar columns of one trial (``METRIC_COLUMNS`` plus ``diverged``, ``diverged_at``).

    ``coh_min`` is the minimum over ``0 < f <= fmax`` of the four multiple coherences (both
    position outputs and both force outputs): the weakest of the spectra ``Z = T R^-1``
    is built from. ``rel_error`` is ``phi_T`` over the mean largest singular value of the
    arm's true impedance.
    """
    f = outcome_i["f"]
    zt = np.asarray(point_arm(point).impedance(f))
    scale = float(np.mean(np.linalg.svd(zt, compute_uv=False)[:, 0]))
    cx, cf = np.asarray(outcome_i["coh_multiple_x"]), np.asarray(outcome_i["coh_multiple_fh"])
    row = dict(phi_T=float(outcome_i["phi_T"]), **_cells("phi", outcome_i["phi_ij"]))
    row["rel_error"] = row["phi_T"] / scale
    row["coh_min"] = float(min(cx.min(), cf.min()))
    for name, c in (("x", cx), ("fh", cf)):
        for j in range(2):
            row[f"coh_{name}{j + 1}_min"] = float(c[:, j].min())
            row[f"coh_{name}{j + 1}_median"] = float(np.median(c[:, j]))
    row["input_coherence_max"] = float(outcome_i["input_coherence"])
    for p, field in (("M", "mass"), ("B", "damping"), ("K", "stiffness")):
        row |= _cells(p, fit_i[field])
        row |= {k + "_se": v for k, v in _cells(p, fit_i[field + "_se"]).items()}
    row |= _cells("vaf", fit_i["vaf"])
    row["vaf_overall"] = float(fit_i["vaf_overall"])
    row = {k: row[k] for k in METRIC_COLUMNS}
    row["diverged"] = bool(outcome_i["diverged"])
    row["diverged_at"] = int(outcome_i["diverged_at"])
    return row


_vfit = jax.jit(jax.vmap(fit_impedance))


# --- running ----------------------------------------------------------------------------------


@dataclasses.dataclass
class _Perturbations:
    base_seed: int
    cache: dict = dataclasses.field(default_factory=dict)

    def key(self, seed: int):
        return jax.random.fold_in(jax.random.PRNGKey(self.base_seed), seed)

    def __call__(self, seed: int, n: int, peak) -> np.ndarray:
        k = (seed, n, tuple(peak))
        if k not in self.cache:
            self.cache[k] = np.asarray(perturbation(self.key(seed), n, np.asarray(peak)))
        return self.cache[k]


def _noisy(point) -> bool:
    return point["force_noise"] > 0 or point["velocity_noise"] > 0


def _batches(settings: SweepSettings, todo, batch_size: int) -> list[list]:
    groups: dict[tuple, list] = {}
    for i, s in todo:
        groups.setdefault(static_group(settings.points[i]), []).append((i, s))
    out = []
    for g in groups.values():  # equal batches: one compiled shape per group
        per = math.ceil(len(g) / math.ceil(len(g) / batch_size))
        out += [g[j : j + per] for j in range(0, len(g), per)]
    return out


def run_batch(settings: SweepSettings, batch, signals, *, mesh=None, chunk_seconds: float = 5.0, progress=None):
    """Simulate and assess one batch of ``(point index, seed)`` sharing a ``static_group``;
    returns ``(rows, arrays)``, per trial the metrics dict and the estimate's arrays."""
    points = [settings.points[i] for i, _ in batch]
    n = n_samples(points[0])
    params = stack_trials([build_trial(p) for p in points])
    f_delta = np.stack([signals(s, n, p["peak"]) for p, (_, s) in zip(points, batch, strict=True)])
    keys = None
    if any(_noisy(p) for p in points):
        keys = np.stack([np.asarray(jax.random.key_data(jax.random.fold_in(signals.key(s), 1))) for _, s in batch])
    sim = simulate_batch(
        params,
        f_delta,
        keys=keys,
        numerics=settings.numerics,
        mesh=mesh,
        chunk_samples=max(1, int(chunk_seconds * 1000)),
        progress=progress,
    )
    outcome = assess_batch(params, f_delta, sim, point_welch(points[0]), mesh=mesh)
    fits = jax.tree.map(np.asarray, _vfit(outcome.estimate))
    rows, arrays = [], []
    for j, point in enumerate(points):
        est = {name: np.asarray(getattr(outcome.estimate, name)[j]) for name in ESTIMATE_FIELDS}
        out_j = dict(
            est,
            phi_T=outcome.phi_T[j],
            phi_ij=outcome.phi_ij[j],
            input_coherence=outcome.input_coherence[j],
            diverged=sim.diverged[j],
            diverged_at=sim.diverged_at[j],
        )
        fit_j = {k: v[j] for k, v in fits._asdict().items()}
        rows.append(trial_metrics(point, out_j, fit_j))
        arrays.append(est | {f"fit_{k}": v for k, v in fit_j.items()})
    return rows, arrays


def compute(
    settings: SweepSettings,
    out,
    todo,
    *,
    batch_size: int = 64,
    chunk_seconds: float = 5.0,
    progress: Callable[[dict], None] | None = None,
    stop_after_batches: int | None = None,
) -> list[str]:
    """Run the ``todo`` trials in batches and save each as a checked record as soon as its
    batch finishes; returns the ids computed.

    ``progress`` receives a dict after every chunk: ``done``/``total`` (trial samples),
    ``trials_done``, ``trials_total``, ``elapsed_s`` and ``eta_s``, the latter from the
    rate of the chunks that compiled nothing (the first chunk of each new batch shape
    pays for compilation; NaN until a chunk has run without compiling)."""
    out = pathlib.Path(out)
    mesh = make_mesh()
    signals = _Perturbations(settings.base_seed)
    total = sum(n_samples(settings.points[i]) for i, _ in todo)
    start = time.perf_counter()
    # "last": when the previous chunk reported, so that estimating and saving a batch count
    # towards the rate (they are part of every trial's cost)
    state = dict(done=0, trials=0, t_fresh=0.0, n_fresh=0, last=start)
    shapes_seen: set = set()
    computed = []
    for b_index, batch in enumerate(_batches(settings, todo, batch_size)):
        if stop_after_batches is not None and b_index >= stop_after_batches:
            break
        shape = (
            static_group(settings.points[batch[0][0]]),
            len(batch),
            any(_noisy(settings.points[i]) for i, _ in batch),
        )
        compiling = [shape not in shapes_seen]
        shapes_seen.add(shape)
        base = state["done"]

        def on_chunk(done, _total, _elapsed, base=base, compiling=compiling):
            now = time.perf_counter()
            step = base + done - state["done"]
            if not compiling[0]:  # chunks that compiled nothing set the rate of the ETA
                state["t_fresh"] += now - state["last"]
                state["n_fresh"] += step
            compiling[0] = False
            state["last"] = now
            state["done"] = base + done
            if progress is not None:
                rate = state["n_fresh"] / state["t_fresh"] if state["t_fresh"] > 0 else float("nan")
                progress(
                    dict(
                        done=state["done"],
                        total=total,
                        trials_done=state["trials"],
                        trials_total=len(todo),
                        elapsed_s=now - start,
                        eta_s=(total - state["done"]) / rate if rate > 0 else float("nan"),
                    )
                )

        t0 = time.perf_counter()
        rows, arrays = run_batch(settings, batch, signals, mesh=mesh, chunk_seconds=chunk_seconds, progress=on_chunk)
        wall = time.perf_counter() - t0
        for (i, s), row, arr in zip(batch, rows, arrays, strict=True):
            point = settings.points[i]
            tid = trial_id(settings, point, s)
            meta = dict(id=tid, point_index=i, seed=s, metrics=row, batch_wall_s=wall, batch_size=len(batch))
            if distributed.is_writer():  # every process holds every row (gathered); one writes
                save_record(
                    out / "trials" / f"{tid}.npz", settings=settings.trial_settings(point, s), arrays=arr, meta=meta
                )
            computed.append(tid)
        state["trials"] += len(batch)
    return computed


# --- tables and statistics -------------------------------------------------------------------


def point_columns(point: Mapping) -> dict:
    """The settings of a point as flat table columns (``arm`` a location or ``user-<hash>``;
    ``peak`` as ``peak_x``, ``peak_y`` [N]; ``tau_s`` [N m] derived from the ratio)."""
    arm = point["arm"] if isinstance(point["arm"], int) else f"user-{settings_key(dict(arm=point['arm']))[:8]}"
    cols = {}
    for k, v in point.items():
        if k == "arm":
            cols["arm"] = arm
        elif k == "peak":
            cols["peak_x"], cols["peak_y"] = v
        elif k == "window":
            cols["window"] = v if isinstance(v, str) else ":".join(map(str, v))
        else:
            cols[k] = v
        if k == "stiction_ratio":
            cols["tau_s"] = point["tau_c"] * point["stiction_ratio"]
    return cols


def mean_ci(values, level: float = CI_LEVEL) -> dict:
    """``n``, ``mean``, ``sd`` (``n - 1``), and the two-sided t-interval of the mean
    ``ci_lo``, ``ci_hi`` of the finite ``values`` (NaN where undefined: no interval from
    fewer than two values)."""
    v = np.asarray([x for x in values if x is not None and math.isfinite(x)], dtype=float)
    n = len(v)
    mean = float(v.mean()) if n else math.nan
    sd = float(v.std(ddof=1)) if n > 1 else (0.0 if n == 1 else math.nan)
    half = float(stats.t.ppf(0.5 + level / 2, n - 1) * sd / math.sqrt(n)) if n > 1 else math.nan
    return dict(n=n, mean=mean, sd=sd, ci_lo=mean - half, ci_hi=mean + half)


def summarize(settings: SweepSettings, rows: list[dict]) -> list[dict]:
    """Per point: ``point`` (its settings), ``trials`` found, ``n`` sound, ``diverged`` (count
    and seeds), and for each of ``METRIC_COLUMNS`` the ``mean_ci`` over the sound seeds
    (diverged trials are left out of every statistic)."""
    by_point: dict[int, list] = {}
    for r in rows:
        by_point.setdefault(r["point_index"], []).append(r)
    out = []
    for i, point in enumerate(settings.points):
        rs = by_point.get(i, [])
        sound = [r for r in rs if not r["diverged"]]
        out.append(
            dict(
                point=point,
                trials=len(rs),
                n=len(sound),
                diverged=len(rs) - len(sound),
                diverged_seeds=[r["seed"] for r in rs if r["diverged"]],
                stats={m: mean_ci([r[m] for r in sound]) for m in METRIC_COLUMNS},
            )
        )
    return out


def _csv_value(v):
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return ""
    if isinstance(v, float):
        return repr(v)
    return v


def write_csv(path, rows: list[dict]) -> None:
    """Write ``rows`` (dicts with the same keys) as CSV, atomically; empty cells for missing
    or non-finite numbers."""
    buf = io.StringIO()
    if rows:
        writer = csv.DictWriter(buf, fieldnames=list(rows[0]), lineterminator="\n")
        writer.writeheader()
        for r in rows:
            writer.writerow({k: _csv_value(v) for k, v in r.items()})
    atomic_write_text(path, buf.getvalue())


def summary_table(summary: list[dict], numerics: Mapping) -> list[dict]:
    """``summary`` as flat CSV rows: point columns, counts, and ``<metric>_<stat>`` columns."""
    table = []
    for entry in summary:
        row = point_columns(entry["point"]) | dict(numerics)
        row |= dict(trials=entry["trials"], n=entry["n"], diverged=entry["diverged"])
        for m, st in entry["stats"].items():
            row |= {f"{m}_{k}": st[k] for k in ("mean", "sd", "ci_lo", "ci_hi")}
        table.append(row)
    return table


def swept_settings(points: list[Mapping]) -> list[str]:
    """The settings that take more than one value across ``points`` (``None``, a setting that
    does not apply, such as PD's ``mhat``, is not a value)."""
    return [k for k in POINT_DEFAULTS if len({json.dumps(p[k]) for p in points if p[k] is not None}) > 1]


def _numeric(points, name) -> bool:
    values = [p[name] for p in points if p[name] is not None]
    return (
        bool(values) and name != "arm" and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values)
    )


def plot_summary(summary: list[dict], path, *, x: str | None = None, metric: str = "phi_T") -> pathlib.Path:
    """Draw ``metric``'s mean with its 95% interval (a band; none for one seed) against the
    swept numeric setting ``x`` (default: the first swept numeric setting), one line per
    combination of the other swept settings. The x axis is logarithmic when the positive
    values span two decades or more (symlog when 0 is among them); y starts at 0. With no
    numeric setting swept, one bar per point. Returns ``path``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    points = [e["point"] for e in summary]
    swept = swept_settings(points)
    numeric = [k for k in swept if _numeric(points, k)]
    if x is None and numeric:
        x = numeric[0]
    if x is not None and x not in POINT_DEFAULTS:
        raise ValueError(f"cannot plot against {x!r}: not a setting")
    unit = "N/m" if metric.startswith("phi") else ""
    fig, ax = plt.subplots(figsize=(7, 4.5))
    if x is None:
        labels = [", ".join(f"{k}={point_columns(p)[k]}" for k in swept) or "all" for p in points]
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
            label = ", ".join(f"{k}={point_columns(e['point'])[k]}" for k in others) or metric
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
        unit_x = POINT_UNITS.get(x)
        ax.set_xlabel(f"{x} [{unit_x}]" if unit_x else x)
        if len(lines) > 1 or others:
            ax.legend(fontsize=7)
    ax.set_ylim(bottom=0)
    ax.set_ylabel(f"{metric} [{unit}] (mean, 95% CI)" if unit else f"{metric} (mean, 95% CI)")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    path = pathlib.Path(path)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


# --- the whole run ----------------------------------------------------------------------------


def numerics_check(settings: SweepSettings, rows: list[dict], sample: int, *, mesh=None) -> dict:
    """Re-run ``sample`` trials of each static group (spread over it) at 4x the substeps
    (``check_numerics``) and report the observed relative ``phi_T`` error."""
    signals = _Perturbations(settings.base_seed)
    by_group: dict[tuple, list] = {}
    for r in sorted(rows, key=lambda r: (r["point_index"], r["seed"])):
        by_group.setdefault(static_group(settings.points[r["point_index"]]), []).append(r)
    errors, diverged, checked = [], 0, 0
    for group in by_group.values():
        idx = np.unique(np.linspace(0, len(group) - 1, min(sample, len(group))).round().astype(int))
        pick = [group[j] for j in idx]
        points = [settings.points[r["point_index"]] for r in pick]
        params = stack_trials([build_trial(p) for p in points])
        n = n_samples(points[0])
        f_delta = np.stack([signals(r["seed"], n, p["peak"]) for r, p in zip(pick, points, strict=True)])
        keys = None
        if any(_noisy(p) for p in points):
            keys = np.stack(
                [np.asarray(jax.random.key_data(jax.random.fold_in(signals.key(r["seed"]), 1))) for r in pick]
            )
        phi = np.array([math.nan if r["diverged"] else r["phi_T"] for r in pick])
        res = check_numerics(
            params,
            f_delta,
            numerics=settings.numerics,
            sample=len(pick),
            phi_T=phi,
            welch=point_welch(points[0]),
            keys=keys,
            mesh=mesh,
        )
        errors += [float(e) for e in res.rel_error if math.isfinite(e)]
        diverged += res.diverged
        checked += len(pick)
    return dict(
        sample_per_group=sample,
        trials_checked=checked,
        refined_substeps=settings.substeps * 4,
        max_rel_error=max(errors) if errors else None,
        diverged=diverged,
    )


def collect(settings: SweepSettings, out, *, warn: Callable[[str], None] = _warn_stderr) -> tuple[list[dict], list]:
    """The rows of every trial with a valid record (``point_index``, ``seed``, point columns,
    numerics, metrics), and the ``(point index, seed)`` pairs missing."""
    records, missing = trial_status(settings, out, warn=warn)
    rows = []
    num = dict(method=settings.method, substeps=settings.substeps)
    for (i, s), rec in sorted(records.items()):
        row = dict(point_index=i, seed=s, trial_id=rec.meta["id"]) | point_columns(settings.points[i])
        rows.append(row | dict(base_seed=settings.base_seed) | num | rec.meta["metrics"])
    return rows, missing


def write_outputs(
    settings: SweepSettings, out, *, check: dict | None = None, x: str | None = None, warn=_warn_stderr
) -> dict:
    """Write ``trials.csv``, ``summary.csv``, ``summary.json`` and the figure from the valid
    trial records in ``out``; returns the ``summary.json`` contents."""
    out = pathlib.Path(out)
    rows, missing = collect(settings, out, warn=warn)
    write_csv(out / "trials.csv", rows)
    summary = summarize(settings, rows)
    write_csv(out / "summary.csv", summary_table(summary, dict(method=settings.method, substeps=settings.substeps)))
    swept = swept_settings(list(settings.points))
    numeric = [k for k in swept if _numeric(list(settings.points), k)]
    x = x or (numeric[0] if numeric else None)
    figure = plot_summary(summary, out / f"{x or 'conditions'}.png", x=x) if rows else None
    run = read_run(out)
    if check is None:  # keep the check of an earlier call on this run, if any
        try:
            previous = read_json(out / "summary.json")
            if isinstance(previous, dict) and previous.get("key") == run["key"]:
                check = previous.get("numerics_check")
        except ResultsError:
            pass
    result = to_jsonable(
        dict(
            kind="sweep",
            format=RUN_FORMAT,
            settings=run["settings"],
            key=run["key"],
            complete=not missing,
            trials_expected=len(settings.points) * settings.seeds,
            trials=len(rows),
            missing=[dict(point_index=i, seed=s) for i, s in missing],
            diverged=[r["trial_id"] for r in rows if r["diverged"]],
            swept=swept,
            figure=None if figure is None else figure.name,
            numerics_check=check,
            conditions=summary,
        )
    )
    atomic_write_json(out / "summary.json", result)
    return result


def run_sweep(
    settings: SweepSettings,
    out,
    *,
    batch_size: int = 64,
    chunk_seconds: float = 5.0,
    check: int = 0,
    x: str | None = None,
    progress: Callable[[dict], None] | None = None,
    stop_after_batches: int | None = None,
    warn: Callable[[str], None] = _warn_stderr,
    on_start: Callable[[int, int], None] | None = None,
) -> dict:
    """Run a sweep in folder ``out`` (created if needed) and write its tables and figure.

    Holds ``out``'s ``RunLock`` throughout; a folder holding a sweep with other settings
    is refused (one line naming the differences); trials with a valid record are reused,
    others (missing, truncated, altered, foreign: named in a warning) are computed.
    ``check`` > 0 re-runs that many trials per static group at 4x the substeps and puts
    the observed maximum relative ``phi_T`` error into ``summary.json``. Returns the
    ``summary.json`` contents plus ``computed`` (ids of the trials run now). ``on_start``
    is called as ``on_start(trials_on_disk, trials_to_run)`` once the folder is checked,
    before any computation (by process 0 only, in a ``jax.distributed`` job).
    """
    settings.validate()
    if x is not None and x not in POINT_DEFAULTS:
        raise ValueError(f"cannot plot against {x!r}: not a setting; known: {', '.join(POINT_DEFAULTS)}")
    if batch_size < 1:
        raise ValueError(f"batch_size must be >= 1, got {batch_size}")
    out = pathlib.Path(out)
    if check > 0 and distributed.is_distributed():
        raise ValueError("check re-runs trials on one process: run it without the distributed options")
    with contextlib.ExitStack() as stack:
        # In a jax.distributed job only process 0 touches the folder; every process gets its
        # list of trials to run, so all run the same batches in the same order.
        todo = error = None
        if distributed.is_writer():
            try:
                stack.enter_context(RunLock(out))
                prepare_output(out, settings)
                _, todo = trial_status(settings, out, warn=warn)
            except Exception as err:  # shared with the other processes, then raised
                error = err
        order = [(i, s) for i in range(len(settings.points)) for s in range(settings.seeds)]
        todo = distributed.share_start(settings_key(settings.run_settings()), order, todo, error)
        if on_start is not None and distributed.is_writer():
            on_start(len(order) - len(todo), len(todo))
        computed = compute(
            settings,
            out,
            todo,
            batch_size=batch_size,
            chunk_seconds=chunk_seconds,
            progress=progress,
            stop_after_batches=stop_after_batches,
        )
        if not distributed.is_writer():
            return dict(computed=computed)
        report = None
        if check > 0:
            rows, _ = collect(settings, out, warn=lambda _: None)
            report = numerics_check(settings, rows, check) if rows else None
        result = write_outputs(settings, out, check=report, x=x, warn=lambda _: None)
    return result | dict(computed=computed)


# --- thresholds -------------------------------------------------------------------------------


def first_crossing(x, y, level: float, *, above: bool = True) -> float:
    """The smallest ``x`` where ``y`` first reaches ``level`` (``y >= level`` if ``above``,
    else ``y < level``), interpolated between the grid points around the crossing: ``y``
    linear in ``log x`` between positive points, linear in ``x`` from ``x = 0``. NaN if it
    is never reached; ``x[0]`` if it is reached there. ``x`` ascending, ``(P,)``."""
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    hit = (y >= level) if above else (y < level)
    hit &= np.isfinite(y)
    if not hit.any():
        return math.nan
    k = int(np.argmax(hit))
    if k == 0:
        return float(x[0])
    x0, x1, y0, y1 = x[k - 1], x[k], y[k - 1], y[k]
    if not math.isfinite(y0) or y1 == y0:
        return float(x1)
    t = (level - y0) / (y1 - y0)
    if x0 > 0:
        return float(math.exp(math.log(x0) + t * (math.log(x1) - math.log(x0))))
    return float(x0 + t * (x1 - x0))


def bootstrap_crossing(
    x, values, level_fn: Callable[[np.ndarray], float], *, above: bool = True, n_boot: int = 2000, seed: int = 0
) -> dict:
    """The crossing of the seed-mean curve and its percentile 95% bootstrap interval over seeds.

    ``values`` ``(S, P)``: one curve per seed over the ascending grid ``x`` ``(P,)`` (NaN for
    a diverged trial, left out of the means). ``level_fn(mean curve)`` gives the level to
    cross (e.g. twice the curve's first value). Seeds are resampled whole (the grid points
    of one seed share its perturbation), ``n_boot`` times with a fixed PRNG. Resamples
    that never cross count as beyond the grid's end. Returns ``value`` (NaN: not reached),
    ``ci_lo``, ``ci_hi`` (``inf`` when more than 2.5% of the resamples do not cross),
    ``not_reached`` (fraction of resamples), ``seeds``.
    """
    v = np.asarray(values, dtype=float)
    x = np.asarray(x, dtype=float)

    def crossing(curves):
        with warnings.catch_warnings():  # a grid point where every resampled seed diverged: NaN
            warnings.simplefilter("ignore", RuntimeWarning)
            mean = np.nanmean(curves, axis=0)
        return first_crossing(x, mean, level_fn(mean), above=above)

    value = crossing(v)
    rng = np.random.default_rng(seed)
    s = v.shape[0]
    boots = np.array([crossing(v[rng.integers(0, s, s)]) for _ in range(n_boot)]) if s > 1 else np.array([value])
    boots = np.where(np.isnan(boots), np.inf, boots)
    q = [(1 - CI_LEVEL) / 2, 1 - (1 - CI_LEVEL) / 2]
    lo, hi = np.quantile(boots, q, method="inverted_cdf") if s > 1 else (math.nan, math.nan)
    return dict(value=value, ci_lo=float(lo), ci_hi=float(hi), not_reached=float(np.mean(np.isinf(boots))), seeds=s)
