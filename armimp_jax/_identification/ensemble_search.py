"""The model route's search over an ensemble, and the check of its intervals
(``ensemble_identify.py``'s module docstring says why).

The search: chord iterations, each holding the loop linearised at its start (one binding serves
every repetition and every step) until its step is below ``TOLERANCE`` SE, re-linearised at each
answer until the step from there is below ``REFRESH_TOLERANCE`` SE. The check: ``CHECK_DRAWS``
ensembles simulated at the answer (the lab's perturbations, the model's noise), each refitted by the
chord held there; each entry's RMS error about the answer over its SE on the bound.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from scipy.stats import chi2

from . import path as ph
from . import path_bound as pb

TOLERANCE = 0.01  # a step below this fraction of every SE ends a chord
REFRESH_TOLERANCE = 0.05  # [SE] the search re-linearises at its answer until the step from there is below this
MAX_REFRESHES = 4  # re-linearisations at most (1-2 took it below 0.05 SE in 11 paired ensembles)
# Ensembles simulated at the answer (the lab's perturbations, the model's noise) whose answers' spread
# checks the bound's SEs; an entry's interval is widened to that spread where it is larger.
CHECK_DRAWS = 16
SPREAD_FALSE_ALARM = 0.05  # a spread at the bound is warned of this often over all the fit's entries
CHECK_STREAM = 2**31 - 3  # the check's draws: their own stream, folded into any key (as ef.DRAW_STREAM)


class Linear(eqx.Module):
    """The loop linearised at ``p``: its filter, noise-free responses, whitened centred Jacobian
    ``(R, N, 4, n)`` and ``(sum_r J_r^T J_r)^-1``."""

    p: np.ndarray
    filt: ph.PathFilter
    mu: jnp.ndarray
    wj: jnp.ndarray
    h_inv: np.ndarray


def linearise(layout, model, p, f, numerics) -> Linear:
    filt, mu, jac = ph.linearised_at(layout, model, jnp.asarray(p), f, numerics)
    wj = ph.whiten_centred(filt, jac)
    return Linear(p, filt, mu, wj, pb.whitened_inverse(wj, layout.labels(), "identify"))


def gls_step(lin: Linear, mu, y) -> np.ndarray:
    return lin.h_inv @ np.asarray(jnp.einsum("rkip,rki->p", lin.wj, ph.whiten_centred(lin.filt, y - mu)))


def search(layout, model, p, f, y, numerics, max_steps):
    """Chord iterations (module docstring), each from a refreshed linearisation, until the step the
    loop linearised at the answer would take is below ``REFRESH_TOLERANCE`` SE: ``(p, steps,
    converged, message, linear at p)``; a step that takes a simulated reach to divergence ends it
    at the last sound ``p``."""
    if np.any(np.asarray(ph.responses(layout, model, jnp.asarray(p), f, numerics)[1])):
        return p, 0, False, "the simulated reaches diverge at the start: check the model, or give start=", None
    lin, steps, settled = linearise(layout, model, p, f, numerics), 0, None
    for _ in range(MAX_REFRESHES + 1):
        p, taken, message = chord(layout, model, lin, f, y, numerics, max_steps)
        steps += taken
        if message:  # keep an earlier chord's answer, if one settled (its refreshed step is reported)
            return (settled.p, steps, True, "", settled) if settled is not None else (p, steps, False, message, None)
        settled = lin = linearise(layout, model, p, f, numerics)
        if refreshed(lin, y) < REFRESH_TOLERANCE:
            break
    return p, steps, True, "", lin


def chord(layout, model, lin: Linear, f, y, numerics, max_steps) -> tuple[np.ndarray, int, str]:
    """Steps with ``lin``'s Jacobian and filter held, from ``lin.p``, until one is below ``TOLERANCE``
    of every SE: ``(p, steps, message)``."""
    p, mu, se = lin.p, lin.mu, np.sqrt(np.diag(lin.h_inv))
    for steps in range(1, max_steps + 1):
        delta = gls_step(lin, mu, y)
        mu_new, diverged = ph.responses(layout, model, jnp.asarray(p + delta), f, numerics)
        if np.any(np.asarray(diverged)):
            return p, steps, "a step took the simulated reaches to divergence: start nearer (start=) or check the model"
        p, mu = p + delta, mu_new
        if np.max(np.abs(delta) / se) < TOLERANCE:
            return p, steps, ""
    return p, max_steps, f"no convergence in {max_steps} steps"


def refreshed(lin: Linear, y) -> float:
    """The largest step, in SEs, the loop linearised at ``lin.p`` would still take."""
    return float(np.max(np.abs(gls_step(lin, lin.mu, y)) / np.sqrt(np.diag(lin.h_inv))))


def at_answer(lin: Linear, y, repetitions):
    """The covariance at the answer (widened by the noise ratio above 1), the noise ratio, and the
    step, in SEs, the loop linearised there would still take."""
    resid = ph.whiten_centred(lin.filt, y - lin.mu)  # the filter at the answer whitens the data anew
    noise_ratio = float(jnp.sum(resid**2)) / ((repetitions - 1) * resid.shape[1] * 4 - lin.p.size)
    return lin.h_inv * max(noise_ratio, 1.0), noise_ratio, refreshed(lin, y)


def check_warnings(check, labels) -> list[str]:
    """What the check of the intervals tells a lab: draws that did not refit, a spread beyond the
    bound's chance (the chi-square bound of as many dof as refits, at ``SPREAD_FALSE_ALARM`` over
    the entries: Bonferroni)."""
    if check is None:
        return []
    spread, refits = check
    if not np.all(np.isfinite(spread)):
        return [
            f"only {refits} of {CHECK_DRAWS} ensembles simulated at the answer refitted (the others diverged or did "
            "not settle): the intervals rest on the loop linearised at the answer alone; treat them as provisional"
        ]
    out = []
    if refits < CHECK_DRAWS:
        out.append(
            f"{CHECK_DRAWS - refits} of {CHECK_DRAWS} ensembles simulated at the answer diverged or did not refit: "
            "the loop is near its limits there; the intervals' check rests on the rest"
        )
    bound = float(np.sqrt(chi2.ppf(1.0 - SPREAD_FALSE_ALARM / spread.size, refits) / refits))
    if np.max(spread) > bound:
        worst = int(np.argmax(spread))
        out.append(
            f"refitted to {refits} ensembles simulated at the answer, the estimates err up to "
            f"{spread[worst]:.2f} times the bound ({labels[worst]}): the hand's excursions bend the loop; those "
            "intervals are widened to it (a stiffer robot, or a smaller perturbation, keeps the loop linear)"
        )
    return out


def spread_ratio(layout, model, lin: Linear, f, numerics, key) -> tuple[np.ndarray, int]:
    """``(ratio (n,), refits)``: each entry's RMS error over the answers to ``CHECK_DRAWS``
    ensembles simulated at the answer (the lab's perturbations, the model's noise; each refitted by
    the chord held there; their truth is the answer) over its SE on the bound (NaN where fewer than
    half of them refit), and how many refit."""
    answers = []
    for d in range(CHECK_DRAWS):
        keys = jax.random.split(jax.random.fold_in(key, d), f.shape[0])
        y, diverged = ph.noisy_responses(layout, model, jnp.asarray(lin.p), f, keys, numerics)
        if np.any(np.asarray(diverged)):
            continue
        p, _, message = chord(layout, model, lin, f, y, numerics, 8)
        if not message:
            answers.append(p)
    if len(answers) < CHECK_DRAWS // 2:
        return np.full(lin.p.size, np.nan), len(answers)
    rms = np.sqrt(np.mean((np.asarray(answers) - lin.p) ** 2, axis=0))
    return rms / np.sqrt(np.diag(lin.h_inv)), len(answers)
