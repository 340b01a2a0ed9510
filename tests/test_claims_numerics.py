"""Statistics tier (``pytest -m stats``): "converged at every friction 0-4 N m" (identify's and
``Numerics()``'s ``GradedARK4`` at 4 substeps: ``aj.solvers.IDENTIFY_NUMERICS``; docs/identification.md
section 3 item 8, docs/performance.md, "The integrators' convergence") on the claim's own terms: PD and IMBIC at their
defaults, Coulomb torques 0, 1e-4, 1e-3, 1e-2, 0.1, 1 and 4 N m (stiction 1.5 times it), the
paper's four arms, 50 s records at its level 1 (key 0), Table 4's Welch settings; against the
same solver at 4 times the substeps, ``phi_T`` and the fitted stiffness within 1e-4 and no
trial diverged. Deterministic: no band, the claim's own tolerance."""

import jax
import numpy as np
import pytest
from claims import report

import armimp_jax as aj
from armimp_jax import presets

pytestmark = pytest.mark.stats

TAUS = (0.0, 1e-4, 1e-3, 1e-2, 0.1, 1.0, 4.0)
SAMPLES = 50_000
TOLERANCE = 1e-4


def _score(trials, f, numerics):
    sim = aj.simulate_batch(trials, f, numerics=numerics)
    out = aj.batch.assess_batch(trials, f, sim)
    fit = jax.jit(jax.vmap(lambda e: aj.fit_impedance(e, acquisition="plain", se="residual").stiffness))
    return np.asarray(out.phi_T), np.asarray(fit(out.estimate)), np.asarray(out.diverged)


@pytest.mark.parametrize("controller", ["pd", "imbic"])
def test_identify_numerics_converge_at_every_coulomb_torque(controller):
    cases = [(tau, loc) for tau in TAUS for loc in (1, 2, 3, 4)]
    trials = aj.batch.stack_trials(
        [
            aj.make_trial(
                aj.PD() if controller == "pd" else aj.IMBIC(),
                arm=presets.arm(loc),
                friction=aj.LuGre(tau, 1.5 * tau),
            )
            for tau, loc in cases
        ]
    )
    f1 = np.asarray(aj.perturbation(jax.random.key(0), SAMPLES, presets.perturbation_peak(1)))
    f = np.broadcast_to(f1, (len(cases), SAMPLES, 2))
    coarse = aj.solvers.IDENTIFY_NUMERICS
    fine = aj.Numerics(solver=coarse.solver, substeps=4 * coarse.substeps)
    phi, k, div = _score(trials, f, coarse)
    phi_ref, k_ref, div_ref = _score(trials, f, fine)
    phi_err = np.abs(phi - phi_ref) / phi_ref
    k_err = np.linalg.norm(k - k_ref, axis=(1, 2)) / np.linalg.norm(k_ref, axis=(1, 2))
    worst = {}  # the larger of the two errors, over the arms, per Coulomb torque
    for i, (tau, _) in enumerate(cases):
        worst[f"tau_c={tau:g}"] = max(worst.get(f"tau_c={tau:g}", 0.0), float(phi_err[i]), float(k_err[i]))
    figures = dict(
        solver=str(coarse.method),
        substeps=coarse.substeps,
        largest_phi_T_error=float(phi_err.max()),
        largest_K_error=float(k_err.max()),
        worst_per_tau=worst,
        diverged=int(div.sum() + div_ref.sum()),
    )
    report(f"numerics-{controller}", figures)
    assert not np.any(div) and not np.any(div_ref), figures
    assert phi_err.max() <= TOLERANCE and k_err.max() <= TOLERANCE, figures
