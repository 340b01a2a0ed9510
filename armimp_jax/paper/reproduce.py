"""Run the paper reproduction: batched trials, per-trial files, resume, aggregation.

``run_reproduction`` simulates every (condition, seed) trial that is not on disk yet, in
vmapped, sharded batches grouped by the static settings (controller, acquisition), and
writes each trial as soon as its batch finishes (``trials/<id>.json`` and ``.npz``,
written atomically). An interrupted run therefore keeps every finished batch, and
``resume=True`` computes only the missing trials. ``aggregate`` gathers the trial files
into ``results.json`` / ``results.npz``, from which the report and figures are drawn.

Seeds: trial seed ``s`` draws its perturbation from ``fold_in(PRNGKey(base_seed), s)``
(and further attempts, if input coherence is capped); every condition sees the same
signal shape for the same seed (common random numbers), scaled to its level's peak.
"""

from __future__ import annotations

import dataclasses
import json
import os
import pathlib
import platform
import time
from collections.abc import Callable

import jax
import numpy as np

from .._batch import Welch, assess_batch, make_mesh, simulate_batch
from .._estimate import input_coherence
from .._numerics import Numerics
from .._perturbation import perturbation
from .._simulate import stack_trials
from ._presets import perturbation_peak, trial
from .claims import Condition, evaluate_claims, paper_conditions, trial_id, trial_metrics

ESTIMATE_FIELDS = ("f", "Z", "coh_multiple_x", "coh_partial_x", "coh_multiple_fh", "coh_partial_fh", "coh_inputs")


@dataclasses.dataclass(frozen=True)
class ReproSettings:
    """Everything that fixes the numbers of a reproduction run."""

    seconds: float = 50.0
    substeps: int = 100
    nperseg: int = 8192
    noverlap: int = 6144
    fmax: float = 15.0
    seeds: int = 1
    base_seed: int = 0
    ablation: bool = True
    max_input_coherence: float | None = None  # redraw a seed's perturbation until below this
    mhat: float = 0.25  # IMBIC gain, times the identity [kg]

    @property
    def n_samples(self) -> int:
        return int(round(self.seconds * 1000))

    @property
    def welch(self) -> Welch:
        return Welch(self.nperseg, self.noverlap, self.fmax)

    def validate(self) -> None:
        if self.seeds < 1:
            raise ValueError(f"seeds must be >= 1, got {self.seeds}")
        if self.substeps < 1 or int(self.substeps) != self.substeps:
            raise ValueError(f"substeps must be an integer >= 1, got {self.substeps}")
        if not self.mhat > 0:
            raise ValueError(f"mhat must be > 0 kg, got {self.mhat}")
        if self.max_input_coherence is not None and not 0 < self.max_input_coherence <= 1:
            raise ValueError(f"max_input_coherence must be in (0, 1], got {self.max_input_coherence}")
        try:
            self.welch.check(self.n_samples)
        except ValueError as err:
            raise ValueError(f"--seconds {self.seconds:g}: {err}") from None


QUICK = ReproSettings(seconds=6.0, substeps=10, nperseg=1024, noverlap=768)


def draw_perturbations(settings: ReproSettings, seed: int, levels) -> tuple[dict, float, int]:
    """Perturbations of one seed for each level, the input coherence and the attempt used."""
    base = jax.random.fold_in(jax.random.PRNGKey(settings.base_seed), seed)
    w = settings.welch
    for attempt in range(100):
        key = base if attempt == 0 else jax.random.fold_in(base, attempt)
        sig = {lv: np.asarray(perturbation(key, settings.n_samples, perturbation_peak(lv))) for lv in levels}
        coh = float(input_coherence(sig[levels[0]], fs=w.fs, nperseg=w.nperseg, noverlap=w.noverlap, fmax=w.fmax))
        if settings.max_input_coherence is None or coh < settings.max_input_coherence:
            return sig, coh, attempt
    raise RuntimeError(
        f"seed {seed}: no perturbation with input coherence < {settings.max_input_coherence} in 100 draws"
    )


def _write_atomic(path: pathlib.Path, write: Callable[[pathlib.Path], None]) -> None:
    tmp = path.with_name(path.name + ".tmp")
    write(tmp)
    os.replace(tmp, path)


def _save_npz(path, arrays):
    def write(tmp):
        with open(tmp, "wb") as fh:
            np.savez(fh, **arrays)

    _write_atomic(path, write)


def _save_json(path, obj):
    _write_atomic(path, lambda tmp: tmp.write_text(json.dumps(obj, indent=1)))


def versions() -> dict:
    import jaxlib
    import matplotlib
    import scipy

    from .. import __version__

    return dict(
        armimp_jax=__version__,
        jax=jax.__version__,
        jaxlib=jaxlib.__version__,
        numpy=np.__version__,
        scipy=scipy.__version__,
        matplotlib=matplotlib.__version__,
        python=platform.python_version(),
        backend=jax.default_backend(),
        devices=jax.device_count(),
    )


def prepare_output(out: pathlib.Path, settings: ReproSettings, *, resume: bool) -> None:
    """Check the output folder is writable and (when resuming) that settings match."""
    try:
        (out / "trials").mkdir(parents=True, exist_ok=True)
        probe = out / ".write-test"
        probe.write_text("ok")
        probe.unlink()
    except OSError as err:
        raise ValueError(f"output folder {out} is not writable: {err}") from None
    run_file = out / "run.json"
    if resume and run_file.exists():
        saved = json.loads(run_file.read_text())["settings"]
        if saved != dataclasses.asdict(settings):
            raise ValueError(f"--resume {out}: saved settings {saved} differ from these {dataclasses.asdict(settings)}")
    _save_json(run_file, dict(settings=dataclasses.asdict(settings), versions=versions()))


def run_reproduction(
    settings: ReproSettings,
    out: pathlib.Path,
    *,
    conditions: list[Condition] | None = None,
    batch_size: int = 48,
    chunk_seconds: float = 5.0,
    progress: Callable[[dict], None] | None = None,
    stop_after_batches: int | None = None,
) -> list[str]:
    """Simulate, estimate and score every missing trial; returns the ids computed now.

    ``progress`` receives a dict (``done``/``total`` substep counts, ``trials_done``,
    ``trials_total``, ``elapsed_s``, ``eta_s``) after every chunk. ``stop_after_batches``
    stops early (used to test resuming).
    """
    settings.validate()
    conditions = paper_conditions(ablation=settings.ablation) if conditions is None else conditions
    trials = [(c, s) for c in conditions for s in range(settings.seeds)]
    todo = [(c, s) for c, s in trials if not (out / "trials" / f"{trial_id(c, s)}.json").exists()]
    levels = sorted({c.perturbation for c in conditions})
    mesh = make_mesh()
    per_trial = settings.n_samples * settings.substeps
    total, done_substeps, computed = len(todo) * per_trial, 0, []
    start = time.perf_counter()
    cache: dict[int, tuple] = {}

    def signals(seed):
        if seed not in cache:
            cache[seed] = draw_perturbations(settings, seed, levels)
        return cache[seed]

    groups: dict[tuple, list] = {}
    for c, s in todo:
        groups.setdefault((c.controller, c.acquisition), []).append((c, s))
    batches = [g[i : i + batch_size] for g in groups.values() for i in range(0, len(g), batch_size)]
    for b_index, batch in enumerate(batches):
        if stop_after_batches is not None and b_index >= stop_after_batches:
            break
        t_batch = time.perf_counter()
        params = stack_trials(
            [
                trial(c.controller, c.friction, c.location, mhat=settings.mhat * np.eye(2), acquisition=c.acquisition)
                for c, _ in batch
            ]
        )
        f_delta = np.stack([signals(s)[0][c.perturbation] for c, s in batch])
        base_done = done_substeps

        def on_chunk(trial_samples, _total, _elapsed, base_done=base_done):
            now = base_done + trial_samples * settings.substeps
            elapsed = time.perf_counter() - start
            rate = now / elapsed if elapsed > 0 else 0.0
            if progress is not None:
                progress(
                    dict(
                        done=now,
                        total=total,
                        trials_done=len(computed),
                        trials_total=len(todo),
                        elapsed_s=elapsed,
                        eta_s=(total - now) / rate if rate > 0 else float("nan"),
                    )
                )

        sim = simulate_batch(
            params,
            f_delta,
            numerics=Numerics(substeps=settings.substeps),
            mesh=mesh,
            chunk_samples=int(chunk_seconds * 1000),
            progress=on_chunk,
        )
        outcome = assess_batch(params, f_delta, sim, settings.welch, mesh=mesh)
        done_substeps += len(batch) * per_trial
        wall = time.perf_counter() - t_batch
        for i, (c, s) in enumerate(batch):
            est = {name: np.asarray(getattr(outcome.estimate, name)[i]) for name in ESTIMATE_FIELDS}
            metrics = trial_metrics(est["f"], est["Z"], est, c.location)
            _, coh, attempt = signals(s)
            tid = trial_id(c, s)
            _save_npz(out / "trials" / f"{tid}.npz", est)
            _save_json(
                out / "trials" / f"{tid}.json",
                dict(
                    id=tid,
                    condition=dataclasses.asdict(c),
                    seed=s,
                    perturbation_attempt=attempt,
                    input_coherence_max=coh,
                    diverged=bool(sim.diverged[i]),
                    diverged_at=int(sim.diverged_at[i]),
                    batch_wall_s=wall,
                    batch_size=len(batch),
                    metrics=metrics,
                ),
            )
            computed.append(tid)
    return computed


def load_trials(out: pathlib.Path) -> tuple[list[dict], dict]:
    """All finished trials in ``out/trials``: metadata list and ``{id: arrays}``."""
    metas, arrays = [], {}
    for path in sorted((out / "trials").glob("*.json")):
        meta = json.loads(path.read_text())
        with np.load(path.with_suffix(".npz")) as data:
            arrays[meta["id"]] = {k: data[k] for k in data.files}
        metas.append(meta)
    return metas, arrays


def condition_summary(metas: list[dict]) -> dict:
    """``Condition -> {metric: mean over seeds, metric + "_sd": spread, "n": seeds}``."""
    by_cond: dict[Condition, list] = {}
    for m in metas:
        by_cond.setdefault(Condition(**m["condition"]), []).append(m)
    out = {}
    for cond, group in sorted(by_cond.items()):
        keys = group[0]["metrics"].keys()
        agg = {}
        for k in keys:
            vals = np.array([g["metrics"][k] for g in group], dtype=float)
            agg[k] = vals.mean(axis=0).tolist() if vals.ndim > 1 else float(vals.mean())
            agg[k + "_sd"] = vals.std(axis=0).tolist() if vals.ndim > 1 else float(vals.std())
        agg["n"] = len(group)
        agg["diverged"] = int(sum(g["diverged"] for g in group))
        out[cond] = agg
    return out


def aggregate(out: pathlib.Path, *, complete: bool) -> tuple[dict, dict]:
    """Write ``results.json`` and ``results.npz`` from the trial files; return the results dict
    and the per-trial arrays (as ``load_results`` would read them back)."""
    metas, arrays = load_trials(out)
    run = json.loads((out / "run.json").read_text())
    summary = condition_summary(metas)
    claims = [dataclasses.asdict(c) for c in evaluate_claims(summary)]
    results = dict(
        complete=complete,
        settings=run["settings"],
        versions=run["versions"],
        trials=metas,
        conditions=[dict(condition=dataclasses.asdict(c), **m) for c, m in summary.items()],
        claims=claims,
        wall_s=run.get("wall_s"),
    )
    _save_json(out / "results.json", results)
    ids = [m["id"] for m in metas]
    stacked = {"trial_ids": np.array(ids)}
    if ids:
        stacked |= {name: np.stack([arrays[i][name] for i in ids]) for name in ESTIMATE_FIELDS}
    _save_npz(out / "results.npz", stacked)
    return results, arrays


def load_results(out: pathlib.Path) -> tuple[dict, dict]:
    """``results.json`` and the per-trial arrays from ``results.npz`` (for ``--replot``)."""
    results = json.loads((out / "results.json").read_text())
    with np.load(out / "results.npz") as data:
        ids = [str(i) for i in data["trial_ids"]]
        arrays = {tid: {k: data[k][j] for k in ESTIMATE_FIELDS if k in data.files} for j, tid in enumerate(ids)}
    return results, arrays
