"""The paper's Mhat-tuning experiment: training and held-out batches, the comparison table.

Built on the general tuner (``armimp_jax.study.tune``): IMBIC trials of the paper's arms and
friction levels, perturbation level 1, training and held-out seeds that never overlap.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from .._batch import assess_batch, simulate_batch
from .._estimation.welch import Welch
from .._simulate import stack_trials
from .._solver.numerics import Numerics
from .._solver.rk4 import RK4
from ..presets import perturbation_peak, trial
from ..study.seeds import seed_perturbation
from ..study.tune import TuneConfig, config_settings

TRAIN_SEED_OFFSET = 100  # training and held-out perturbation seeds never overlap
HELDOUT_SEED_OFFSET = 1000


def seed_perturbations(base_seed: int, seeds, n_samples: int, level: int = 1):
    """``(len(seeds), n, 2)`` perturbations [N] from ``fold_in(PRNGKey(base_seed), seed)``
    (``study.seeds``; the seeds given here carry the training or held-out offset)."""
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
        phis = np.empty(len(cells))
        bad = False
        for start in range(0, len(cells), batch_size):
            chunk = cells[start : start + batch_size]
            params = stack_trials([trial("imbic", fr, loc, mhat=np.asarray(mhat)) for fr, loc, _ in chunk])
            f_delta = np.stack([signals[i] for _, _, i in chunk])
            sim = simulate_batch(params, f_delta, numerics=paper_rk4, chunk_samples=min(n, 10_000))
            res = assess_batch(params, f_delta, sim, welch)
            phis[start : start + len(chunk)] = res.phi_T
            bad |= bool(np.any(res.diverged))
        out[name] = phis.reshape(len(frictions), len(locations), len(seeds))
        if bad:
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
