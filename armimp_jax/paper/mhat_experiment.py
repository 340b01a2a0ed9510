"""The paper's Mhat-tuning experiment: training and held-out batches, the tuning run as a
specification of the study engine, and the comparison table.

Built on the general tuner (``armimp_jax.study.design.tuning``): IMBIC trials of the paper's arms and
friction levels, perturbation level 1, training and held-out seeds that never overlap.
``Tuning`` is the run: a trial is one iteration of the optimiser (0: the start), its record
the ``TuneState`` after it, so ``engine.run`` resumes a run where it stopped and
``--iterations`` may grow; ``tune_mhat`` runs it and writes ``mhat.json``,
``loss_curve.png`` and the held-out comparison (``comparison.md`` and ``.json``).
"""

from __future__ import annotations

import pathlib
import time
from collections.abc import Callable

import jax.numpy as jnp
import numpy as np

from .._batch import assess_batch, simulate_batch
from .._design.descent import optimizer_or_default
from .._estimation.welch import Welch
from .._simulate import stack_trials
from .._solver.numerics import Numerics
from .._solver.rk4 import RK4
from ..presets import perturbation_peak, trial
from ..study.design.tuning import (
    TuneConfig,
    TuneState,
    config_settings,
    load_state,
    make_trainer,
    mhat_from_theta,
    start_state,
    state_arrays,
    step_state,
    theta_from_mhat,
)
from ..study.runs import engine
from ..study.runs.console import Console
from ..study.runs.results import (
    atomic_write_json,
    atomic_write_text,
    describe_difference,
    settings_key,
    stamped,
    to_jsonable,
)
from ..study.runs.runfolder import StudyRun
from ..study.runs.seeds import seed_perturbation

TRAIN_SEED_OFFSET = 100  # training and held-out perturbation seeds never overlap
HELDOUT_SEED_OFFSET = 1000


def seed_perturbations(base_seed: int, seeds, n_samples: int, level: int = 1):
    """``(len(seeds), n, 2)`` perturbations [N] from ``fold_in(PRNGKey(base_seed), seed)``
    (``study.runs.seeds``; the seeds given here carry the training or held-out offset)."""
    return np.stack([seed_perturbation(base_seed, s, n_samples, perturbation_peak(level)) for s in seeds])


def training_numerics(substeps: int, *, kernel: str = "grad", checkpoint: str = "substep") -> Numerics:
    """The tuner's numerics: the RK4 kernel arranged for reverse mode, and every substep's
    carry on the tape (96 bytes per trial-substep: 31 MB for a 16 s trial at 20 substeps;
    use ``checkpoint="period"`` for batches that would not fit)."""
    return Numerics(solver=RK4(kernel=kernel), substeps=substeps, checkpoint=checkpoint)


def training_batch(frictions, locations, seeds, *, seconds: float, base_seed: int = 0):
    """Stacked IMBIC trials of the paper (friction x location x seed) and their perturbations."""
    n = int(round(seconds * 1000))
    signals = seed_perturbations(base_seed, [TRAIN_SEED_OFFSET + s for s in seeds], n)
    params, f_delta = [], []
    for fr in frictions:
        for loc in locations:
            for i, _ in enumerate(seeds):
                params.append(trial("imbic", fr, loc))
                f_delta.append(signals[i])
    return stack_trials(params), jnp.asarray(np.stack(f_delta))


def training_settings(
    config: TuneConfig, *, frictions, locations, seeds, seconds: float, welch: Welch, start_mhat, base_seed: int = 0
) -> dict:
    """The settings a tuning state of this experiment is saved with (``tune.save_state``):
    the tuner's options (``config_settings``), the training batch (friction levels,
    locations, seeds, record length [s], Welch settings, base seed) and the starting
    ``Mhat`` [kg]."""
    return dict(
        tuner=config_settings(config),
        training=dict(
            frictions=[int(f) for f in frictions],
            locations=[int(loc) for loc in locations],
            seeds=[int(s) for s in seeds],
            seed_offset=TRAIN_SEED_OFFSET,
            perturbation_level=1,
            seconds=float(seconds),
            welch=welch._asdict(),
            base_seed=int(base_seed),
        ),
        start_mhat=np.asarray(start_mhat, dtype=float).tolist(),
    )


def heldout_phi(
    mhats: dict,
    *,
    frictions=(0, 1, 2),
    locations=(1, 2, 3, 4),
    seeds=(0, 1),
    seconds: float = 50.0,
    substeps: int = 100,
    welch: Welch = Welch(),
    base_seed: int = 0,
    batch_size: int = 24,
) -> dict:
    """``phi_T`` of each candidate ``Mhat`` on held-out seeds at the given settings (the
    paper's RK4 at ``substeps``, whatever ``Numerics()`` is).

    Returns ``{name: array (len(frictions), len(locations), len(seeds))}`` plus
    ``"_diverged"``: names whose runs diverged in any trial.
    """
    n = int(round(seconds * 1000))
    welch.check(n)
    signals = seed_perturbations(base_seed, [HELDOUT_SEED_OFFSET + s for s in seeds], n)
    cells = [(fr, loc, i) for fr in frictions for loc in locations for i in range(len(seeds))]
    out, diverged = {}, []
    paper_rk4 = Numerics(solver=RK4(), substeps=substeps)
    for name, mhat in mhats.items():

        def run(chunk, mhat=mhat):
            params = stack_trials([trial("imbic", fr, loc, mhat=np.asarray(mhat)) for fr, loc, _ in chunk])
            f_delta = np.stack([signals[i] for _, _, i in chunk])
            sim = simulate_batch(params, f_delta, numerics=paper_rk4, chunk_samples=min(n, 10_000))
            res = assess_batch(params, f_delta, sim, welch)
            return list(zip(res.phi_T, np.asarray(res.diverged), strict=True))

        results = engine.map_batches(cells, lambda _: name, batch_size, run)
        out[name] = np.array([phi for phi, _ in results]).reshape(len(frictions), len(locations), len(seeds))
        if any(bool(d) for _, d in results):
            diverged.append(name)
    out["_diverged"] = diverged
    return out


def best_candidate(table: dict) -> str | None:
    """The candidate with the lowest mean held-out ``phi_T`` among those that neither
    diverged nor gave a non-finite value (NaN is never lowest); ``None`` if there is none."""
    names = [k for k in table if not k.startswith("_")]
    valid = [n for n in names if n not in table["_diverged"] and np.all(np.isfinite(table[n]))]
    return min(valid, key=lambda n: float(np.mean(table[n]))) if valid else None


def _cell(x: float, fmt: str) -> str:
    return format(x, fmt) if np.isfinite(x) else "—"


def comparison_markdown(table: dict, mhat, *, locations, evals: dict, seeds) -> str:
    """The held-out comparison as Markdown: mean phi_T per friction level and location."""
    names = [k for k in table if not k.startswith("_")]
    frictions = range(next(iter(table[n] for n in names)).shape[0])
    w = evals["welch"]
    lines = [
        f"Held-out phi_T [N/m] (seeds {list(seeds)} offset {HELDOUT_SEED_OFFSET}, {evals['seconds']:g} s, "
        f"{evals['substeps']} substeps, nperseg {w.nperseg}); tuned Mhat = "
        f"{np.round(np.asarray(mhat), 4).tolist()} kg",
        "",
        "| Mhat | " + " | ".join(f"F{f} L{loc}" for f in frictions for loc in locations) + " | mean |",
        "|---|" + "---|" * (len(frictions) * len(locations) + 1),
    ]
    for n in names:
        cells = table[n].mean(axis=2)
        flag = " (diverged)" if n in table["_diverged"] else ""
        lines.append(
            f"| {n}{flag} | "
            + " | ".join(_cell(cells[f, i], ".0f") for f in frictions for i in range(len(locations)))
            + f" | {_cell(table[n].mean(), '.1f')} |"
        )
    best = best_candidate(table)
    if best is None:
        lines += ["", "Lowest mean phi_T: none (every candidate diverged or gave a non-finite phi_T)."]
    else:
        lines += ["", f"Lowest mean phi_T: **{best}** (candidates that diverged are left out)."]
    return "\n".join(lines) + "\n"


# --- the tuning run: a specification of the study engine -----------------------------------


class Tuning:
    """A tuning run of the paper's ``Mhat`` with ``options`` (the ``tune_mhat.py`` options, all
    given): a specification of the study engine whose trial ``i`` is the optimiser's
    iteration ``i`` (0: the start), its record the ``TuneState`` after it. The run's settings
    are the training problem's (``training_settings``: the iteration budget is not one of
    them, so ``--iterations`` may grow on resume). ``log`` receives the optimiser's records."""

    KIND = "tuning"
    FORMAT = 2  # run.json layout (1: the state in one tune_state.npz)
    NOUN = "tuning run"

    def __init__(self, options: dict, *, log: Callable[[dict], None] | None = None):
        self.options = dict(options)
        self.log = log or (lambda _: None)
        o = self.options
        if o["quick"]:
            # 20 substeps: fewer put RK4 near its stability limit on the stiff LuGre bristles
            self.train = dict(seconds=2.5, substeps=20, welch=Welch(512, 384))
            self.evals = dict(seconds=2.5, substeps=20, welch=Welch(512, 384))
            iterations, self.eval_every, self.locations = min(o["iterations"], 3), 0, (1, 2)
        else:
            nperseg = o["train_nperseg"]
            welch = Welch(nperseg, 3 * nperseg // 4)
            self.train = dict(seconds=o["train_seconds"], substeps=o["train_substeps"], welch=welch)
            self.evals = dict(seconds=50.0, substeps=100, welch=Welch())
            iterations, self.eval_every, self.locations = o["iterations"], o["eval_every"], (1, 2, 3, 4)
        self.config = TuneConfig(
            parameterisation=o["parameterisation"],
            learning_rate=o["lr"],
            iterations=iterations,
            mode=o["mode"],
            phi_ij_weight=o["phi_ij_weight"],
            numerics=training_numerics(self.train["substeps"]),
        )
        self.settings = training_settings(
            self.config,
            frictions=o["frictions"],
            locations=self.locations,
            seeds=range(o["train_seeds"]),
            seconds=self.train["seconds"],
            welch=self.train["welch"],
            start_mhat=o["start"] * np.eye(2),
        )

    def validate(self) -> None:
        self.train["welch"].check(int(self.train["seconds"] * 1000))

    def run_settings(self) -> dict:
        return stamped(self.settings)

    def run_extra(self) -> dict:
        return dict(options=self.options)

    describe = staticmethod(describe_difference)

    def trials(self) -> list[int]:
        return list(range(self.config.iterations + 1))

    def trial_record(self, i: int) -> tuple[str, dict]:
        return f"iteration-{i:04d}", stamped(self.settings | dict(iteration=i))

    def group(self, i: int) -> str:
        return "training"

    def samples(self, i: int) -> int:
        return 1

    def runner(self, context: engine.Context) -> engine.BatchRunner:
        """The optimiser, built once per run (the jitted gradient, the placed training batch),
        stepping one iteration per trial from the start or from the last record."""
        held: dict = {}

        def run(batch, progress):
            if not held:
                params, f_delta = training_batch(
                    tuple(self.options["frictions"]),
                    self.locations,
                    tuple(range(self.options["train_seeds"])),
                    seconds=self.train["seconds"],
                )
                held["trainer"] = make_trainer(
                    params, f_delta, self.train["welch"], self.config, context.mesh, self.log
                )
                held["opt"] = optimizer_or_default(None, self.config.learning_rate, where="tune")
            out = []
            for i in batch:
                held["state"] = self._advance(i, held, context.run)
                arrays, notes = state_arrays(held["state"])
                out.append((arrays, notes))
            return out

        return run

    def _advance(self, i: int, held: dict, run: StudyRun) -> TuneState:
        trainer, opt = held["trainer"], held["opt"]
        if i == 0:
            theta0 = theta_from_mhat(self.options["start"] * np.eye(2), self.config.parameterisation)
            state = start_state(trainer, opt, theta0, self.log)
        else:
            state = held.get("state") or self.state(run, i - 1)
            if state.step_scale < self.config.min_step_scale:
                self.log(dict(event="stopping: step scale below minimum"))
                return state
            state = step_state(trainer, opt, state, self.evaluate, self.eval_every)
        self.log(state.history.record(-1))
        return state

    def state(self, run: StudyRun, i: int) -> TuneState:
        """The ``TuneState`` recorded after iteration ``i`` in ``run``, checked."""
        record_id, settings = self.trial_record(i)
        return load_state(run.record_path(record_id), settings, self.config)

    def heldout(self, mhats: dict) -> dict:
        """``heldout_phi`` of ``mhats`` at the run's evaluation settings."""
        e = self.evals
        seeds = tuple(range(self.options["eval_seeds"]))
        return heldout_phi(
            mhats, locations=self.locations, seeds=seeds, seconds=e["seconds"], substeps=e["substeps"], welch=e["welch"]
        )

    def evaluate(self, iteration: int, theta) -> dict:
        phi = self.heldout({"current": np.asarray(mhat_from_theta(theta, self.config.parameterisation))})
        return dict(mean_phi_T=float(phi["current"].mean()), diverged=bool(phi["_diverged"]))


def tuning(options: dict, out, *, resume: bool = False, log=None) -> Tuning:
    """The tuning run asked for: ``options`` as given, or, with ``resume``, the options of the
    run in ``out`` with those given over them (which must not change its settings: one line
    naming the difference otherwise)."""
    if not resume:
        return Tuning(options, log=log)
    study = StudyRun.of(Tuning, out)
    saved = study.read()
    wanted = Tuning(saved["options"] | options, log=log)
    study.check_resume(saved["settings"], wanted.run_settings())
    return wanted


def tune_mhat(spec: Tuning, out, *, resume: bool = False, console: Console | None = None) -> engine.Outcome:
    """Run (or continue) the tuning run ``spec`` in ``out`` on the study engine, then write
    ``mhat.json``, ``loss_curve.png`` and the held-out comparison (``comparison.md`` and
    ``.json``) of the tuned gain against the ``compare`` ones; ``Outcome.finished`` is
    ``(mhat, comparison markdown)``, ``None`` when interrupted (the records resume it)."""
    console = Console(quiet=True) if console is None else console
    started = time.perf_counter()

    def header(on_disk: int, to_run: int) -> str:
        t = spec.train
        going_on = f"continuing from iteration {on_disk - 1}, " if on_disk else ""
        return (
            f"training on {len(spec.options['frictions']) * len(spec.locations) * spec.options['train_seeds']} trials "
            f"of {t['seconds']:g} s ({t['substeps']} substeps), {spec.config.mode}-mode gradients -> {out} "
            f"({going_on}{to_run} iteration(s) to run)"
        )

    def finish(run: StudyRun, outcome: engine.Outcome):
        if run.read().get("options") != to_jsonable(spec.options):  # a resume keeps the last command's options
            run.update(options=spec.options)
        if outcome.interrupted:
            return None
        state = spec.state(run, spec.config.iterations)
        return write_outputs(spec, state, run.path, time.perf_counter() - started)

    return engine.run(
        spec,
        out,
        resume=resume,
        batch_size=1,
        on_start=console.starter(header),
        finish=finish,
        interruptible=True,
    )


def write_outputs(spec: Tuning, state: TuneState, out: pathlib.Path, train_s: float):
    """``mhat.json``, ``loss_curve.png`` and the held-out comparison (``comparison.md`` and
    ``.json``) of the tuned gain against the hand-picked ones; returns ``(mhat, markdown)``."""
    from .plots import loss_curve

    mhat = np.asarray(mhat_from_theta(state.theta, spec.config.parameterisation))
    record = dict(mhat=mhat, settings=spec.settings, key=settings_key(spec.settings), iterations=state.iteration)
    atomic_write_json(out / "mhat.json", record | dict(train_loss=state.value, train_s=train_s))
    loss_curve(state.history.records(), out / "loss_curve.png")
    candidates = {"tuned": mhat} | {f"{v:g} I": v * np.eye(2) for v in spec.options["compare"]}
    table = spec.heldout(candidates)
    seeds = tuple(range(spec.options["eval_seeds"]))
    md = comparison_markdown(table, mhat, locations=spec.locations, evals=spec.evals, seeds=seeds)
    atomic_write_text(out / "comparison.md", md)
    atomic_write_json(out / "comparison.json", table | dict(best=best_candidate(table)))
    return mhat, md
