"""Statistics tier (``pytest -m stats``): the design's Monte Carlo check at its record (README:
"Monte Carlo identification of the designed experiment (30 recordings per arm) put the largest
spread within 0.94-1.16 of the largest prediction at every arm checked").

The full check (``design_imbic.toml``: four arms, 40 steps a round, a round through the
friction, 30 identifications of 2 minutes per arm) takes hours, so this is a smaller design of
the same kind, the one ``design_pd_frictionless.toml`` ships (the reference the friction cases
are set against): PD without friction, the person's force and the sensors' noise of the configs,
their multisine family and limits, the gains and spectrum designed together on the bound
(``aj.design(..., method=aj.experiment.CramerRao(controller=True))``), one arm (location 2), a 10 s record, 10
Adam steps. Then 50 recordings of the designed experiment under new noise, each identified from
the truth (``aj.identify``, 64 draws), and the spread of the six diagonal entries against the
design's own prediction at its record (its bound, exact: no draws). Asserted: the spread is the
prediction, held as a point (a range as wide as the README's 0.94-1.16 would pass a prediction
1.2 times off): the RMS over the targets of spread / prediction within the chi-square band of a
true 1 at their effective dof, each diagonal within its own band (``ALPHA / 6``), and the largest
spread over the largest prediction within its band; failed fits that do not say why in a lab's
terms count against the convergence claim. Reported: the smallest factor on the prediction each
band refuses with power 0.9, and the recordings it would need to refuse 1.2.

Not this case: the calibrated design through IMBIC's friction. On a one-arm 10 s version of it
(10 steps a round, one calibrated round) ``identify`` from the truth converged in 1 of the first
13 recordings of the designed experiment (the others: "no step from iteration 0 kept the
simulations sound and lowered the mismatch"; one also left ``arm.stiffness[0,1]`` barely told),
and with the paper's gains kept the one fit tried took 10 Gauss-Newton steps: too long for a tier
of 50 recordings (docs/performance.md, "The statistics tier")."""

import jax
import numpy as np
import pytest
from acceptance import correlation, sd_band
from claims import ARM, DIAGONAL, RESOLVES, convergence, entries, noise, progress, ratio_check, report, truth_entries

import armimp_jax as aj
from armimp_jax import presets

pytestmark = pytest.mark.stats

RECORD = 10.0  # [s]
RECORDINGS = 50


@pytest.fixture(scope="module")
def designed():
    trial = aj.make_trial(aj.PD(), arm=presets.arm(2), friction=aj.NO_FRICTION, **noise(aj))
    family = aj.signals.multisine(np.geomspace(0.1, 15.0, 16), 1.0)
    limits = aj.experiment.Limits(
        0.66, 2.25, RECORD, peak_displacement=0.010, drift=0.003, min_stiffness=50.0, min_damping=1.0
    )
    res = aj.design(
        trial,
        family,
        free=ARM,
        limits=limits,
        method=aj.experiment.CramerRao(controller=True, precision=0.1),
        steps=10,
        learning_rate=0.1,
        key=jax.random.key(0),
    )
    progress(f"design: {res.time_s:.0f} s, minutes {res.minutes}, controller {res.controller}")
    return res, res.bounds[0].relative()


def test_the_spread_at_the_designs_record_is_its_prediction(designed):
    res, predicted = designed
    assert sorted(predicted) == sorted(DIAGONAL), predicted
    truth, signal = res.trials[0], res.signal
    assert signal.shape == (int(RECORD * 1000), 2)
    sim = jax.jit(aj.simulate, static_argnames="numerics")
    rows, messages, converged = [], [], []
    for seed in range(RECORDINGS):
        rec = sim(truth, signal, key=jax.random.key(50_000 + seed), numerics=aj.solvers.IDENTIFY_NUMERICS)
        assert not bool(rec.diverged), seed
        fit = aj.identify(truth, signal, rec.x, rec.fh, free=ARM, draws=64, key=jax.random.key(seed))
        messages.append(fit.message)
        converged.append(bool(fit.converged))
        progress(f"design check seed {seed}: {fit.time_s:.1f} s, converged {fit.converged}")
        if fit.converged:
            rows.append(entries(fit.values))
    true = truth_entries(truth)
    values = np.array([[r[k] for k in DIAGONAL] for r in rows])
    relative_spread = values.std(axis=0, ddof=1) / np.abs([true[k] for k in DIAGONAL])
    prediction = np.array([predicted[k] for k in DIAGONAL])
    n = len(values)
    figures = ratio_check(relative_spread, prediction, [1.0] * len(DIAGONAL), n, correlation(values))
    largest = float(relative_spread.max() / prediction.max())
    done = convergence(messages, converged)
    figures.update(
        entries=list(DIAGONAL),
        convergence=done,
        largest_over_largest=largest,
        largest_band=sd_band(n - 1),
        minutes=res.minutes,
        controller={k: np.asarray(v).tolist() for k, v in res.controller.items() if k != "type"},
    )
    report("design-check", figures, dict(values=values, true=[true[k] for k in DIAGONAL], predicted=prediction))
    assert done["failed"] - len(done["unexplained"]) <= done["allowed"] and not done["unexplained"], figures
    assert not figures["outside"] and figures["largest_band"].holds(largest), figures
    r = figures["resolution"]
    assert r["rms"] <= RESOLVES["diagonals"] and r["entry"] <= RESOLVES["entry"], r
