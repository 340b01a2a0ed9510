"""Statistics tier (``pytest -m stats``): ``aj.identify``'s 95% intervals, its spread against
``aj.crlb`` and ``aj.predict_se`` against that spread, on the cases of docs/identification.md
section 6 and the README: the paper's arm at location 2, the person's force 0.3 N RMS below
2 Hz, force noise 0.05 N, 2^18-count encoders, instant samples, one perturbation (key 2024: the
paper's level 1, or a 10 N peak where PD slides through its friction), 20 s records; per seed a
recording under new noise (key 10000 + seed) and ``identify`` of the arm's 12 entries from the
truth (key ``seed``, 64 draws). A fit that did not converge counts as a miss (every interval
of its record) unless its message says why in a lab's terms; those are counted apart.

Each claim is asserted with a band (``tests/acceptance.py``, ``tests/claims.py``) that a true
claim leaves with probability at most 0.1%, pooled and per entry; each figure reports the
smallest factor on the SEs (the bound, the prediction) its band refuses with power 0.9 and the
recordings it would need to refuse 1.2 (docs/performance.md, "The statistics tier")."""

import jax
import numpy as np
import pytest
from acceptance import correlation
from claims import (
    ARM,
    DIAGONAL,
    RESOLVES,
    calibration_check,
    convergence,
    diagonal_z,
    entries,
    noise,
    progress,
    ratio_check,
    report,
    truth_entries,
)

import armimp_jax as aj
from armimp_jax import presets

pytestmark = pytest.mark.stats

RECORDINGS = 50
SAMPLES = 20_000  # 20 s at 1 kHz
PREDICT_DRAWS = 256  # predict_se's own Monte Carlo error (about 1 / sqrt(2 R)) kept small beside the spread's
# name: (controller, Coulomb torque [N m] (stiction 1.5 times it), peak [N] or the paper's level 1,
#        claimed spread / bound per diagonal entry (None: no bound through stick-slip)).
# README: "0.86-1.10 of the bound on every M, B, K diagonal under PD and IMBIC without friction
# (IMBIC's x-axis mass 1.3)": measured per entry over 50 recordings, each within about 10% (its
# own chi-square error), so the claim held is a point: at the bound, IMBIC's x-axis mass at 1.3.
AT_BOUND = dict.fromkeys(DIAGONAL, 1.0)
CASES = {
    "pd-a2": ("pd", 0.0, "L1", AT_BOUND),
    "imbic-a2": ("imbic", 0.0, "L1", {**AT_BOUND, "arm.mass[0,0]": 1.3}),
    "pd-a2-1Nm": ("pd", 1.0, 10.0, None),  # through PD's stick-slip: no bound
}


def _case(name):
    controller, tau_c, peak, _ = CASES[name]
    ctrl = aj.PD() if controller == "pd" else aj.IMBIC()
    friction = aj.LuGre(tau_c, 1.5 * tau_c) if tau_c > 0 else aj.NO_FRICTION
    truth = aj.make_trial(ctrl, arm=presets.arm(2), friction=friction, **noise(aj))
    peak = presets.perturbation_peak(1) if peak == "L1" else peak
    return truth, aj.perturbation(jax.random.key(2024), SAMPLES, peak)


@pytest.fixture(scope="module", params=list(CASES))
def monte_carlo(request):
    """The case's recordings, each identified: estimates and SEs of the 12 arm entries (rows:
    converged fits), the count of fits, and the truth and perturbation."""
    name = request.param
    truth, f = _case(name)
    sim = jax.jit(aj.simulate, static_argnames="numerics")
    values, ses, statistics, messages, converged = [], [], set(), [], []
    for seed in range(RECORDINGS):
        rec = sim(truth, f, key=jax.random.key(10_000 + seed), numerics=aj.solvers.IDENTIFY_NUMERICS)
        assert not bool(rec.diverged), (name, seed)
        res = aj.identify(truth, f, rec.x, rec.fh, free=ARM, key=jax.random.key(seed), draws=64)
        messages.append(res.message)
        converged.append(bool(res.converged))
        progress(f"identify {name} seed {seed}: {res.time_s:.1f} s, converged {res.converged}")
        if res.converged:
            values.append(entries(res.values))
            ses.append(entries(res.se))
            statistics.add(res.statistic)
    labels = list(truth_entries(truth))
    return dict(
        name=name,
        truth=truth,
        f=f,
        labels=labels,
        true=np.array([truth_entries(truth)[k] for k in labels]),
        values=np.array([[v[k] for k in labels] for v in values]),
        se=np.array([[s[k] for k in labels] for s in ses]),
        convergence=convergence(messages, converged),
        statistics=sorted(statistics),
    )


def _columns(mc, subset):
    idx = [mc["labels"].index(k) for k in subset]
    return mc["values"][:, idx], mc["se"][:, idx], mc["true"][idx]


def test_converged(monte_carlo):
    """identification.md section 6: 50 of 50 fits converged in each of these cases. Held: the
    failures that say why in a lab's terms within the binomial band of a claim of 98% converged
    (the others are misses in the coverage below)."""
    c = monte_carlo["convergence"]
    report(f"identify-{monte_carlo['name']}-converged", c)
    assert c["failed"] - len(c["unexplained"]) <= c["allowed"], c


def test_intervals_hold_the_truth_95_percent_of_the_time(monte_carlo):
    """README: "its 95% intervals held the truth 0.942-0.953 of the time" (all 12 entries): the
    pooled coverage and RMS of z within their bands of a true 0.95 and 1, and each entry's."""
    values, se, true = _columns(monte_carlo, monte_carlo["labels"])
    z = (values - true) / se
    check = calibration_check(z, unexplained=len(monte_carlo["convergence"]["unexplained"]))
    raw = dict(values=values, se=se, true=true, labels=monte_carlo["labels"])
    report(f"identify-{monte_carlo['name']}-coverage", dict(check, labels=monte_carlo["labels"]), raw)
    assert not check["outside"], check
    r = check["resolution"]
    assert r["rms_z"] <= RESOLVES["entries"] and r["entry_rms_z"] <= RESOLVES["entry"], r


def test_spread_is_at_the_bound(monte_carlo):
    """README: "identify reached 0.86-1.10 of the bound on every M, B, K diagonal under PD and
    IMBIC without friction (IMBIC's x-axis mass 1.3)"."""
    claims = CASES[monte_carlo["name"]][3]
    if claims is None:
        bound = aj.crlb(monte_carlo["truth"], monte_carlo["f"])
        assert not bound.near_linear and np.all(np.isnan(bound.se["arm.stiffness"]))  # stick-slip: no bound
        return
    bound = entries(aj.crlb(monte_carlo["truth"], monte_carlo["f"], free=ARM).se)
    values, _, _ = _columns(monte_carlo, DIAGONAL)
    spread = values.std(axis=0, ddof=1)
    reference = np.array([bound[k] for k in DIAGONAL])
    figures = ratio_check(spread, reference, [claims[k] for k in DIAGONAL], len(values), correlation(values))
    figures["entries"] = list(DIAGONAL)
    report(f"identify-{monte_carlo['name']}-efficiency", figures)
    assert not figures["outside"], figures
    r = figures["resolution"]
    assert r["rms"] <= RESOLVES["diagonals"] and r["entry"] <= RESOLVES["entry"], r


def test_predict_se_is_the_spread(monte_carlo):
    """identification.md sections 4 and 6: ``predict_se`` within 0.83-1.28 of the spread on
    the near-linear cases (0.78-1.32 through stick-slip), and within 0.9-1.1 over the diagonals:
    held as a point, the spread is the prediction (pooled, and each entry at its F band)."""
    pred = entries(aj.predict_se(monte_carlo["truth"], monte_carlo["f"], free=ARM, draws=PREDICT_DRAWS).se)
    values, _, _ = _columns(monte_carlo, DIAGONAL)
    spread = values.std(axis=0, ddof=1)
    reference = np.array([pred[k] for k in DIAGONAL])
    n = len(values)
    figures = ratio_check(spread, reference, [1.0] * len(DIAGONAL), n, correlation(values), PREDICT_DRAWS - 1)
    figures["entries"] = list(DIAGONAL)
    report(f"identify-{monte_carlo['name']}-predict_se", figures)
    assert not figures["outside"], figures
    r = figures["resolution"]
    assert r["rms"] <= RESOLVES["diagonals"] and r["entry"] <= RESOLVES["entry"], r


# identification.md section 6b: per cell, over its six diagonals, coverage 0.92-0.98,
# and per diagonal the SD of z 0.83-1.14 ("honest or errs wide"). Held: the intervals honest, the
# pooled coverage and RMS of z and each diagonal's within their bands (``calibration_check``).
ENTRY_CELLS = ("base", "friction-1")


@pytest.mark.parametrize("cell", ENTRY_CELLS)
def test_intervals_hold_entry_by_entry(cell):
    """identification.md section 6b: the base case (IMBIC through 0.5 N m, a strong
    person's force, 10 s) and its 1 N m cell, 50 recordings each, as
    ``bench_identify_entries.py`` runs them."""
    from armimp_bench import entrywise, protocol

    cases = entrywise.cells([cell])
    rows = []
    for seed in range(RECORDINGS):
        rows.append(protocol.one(cell, seed, cases=cases))
        progress(f"identify {cell} seed {seed}: {rows[-1]['time_s']:.1f} s, converged {rows[-1]['converged']}")
    done = convergence([r["message"] for r in rows], [r["converged"] and not r["diverged"] for r in rows])
    check = calibration_check(diagonal_z(rows), unexplained=len(done["unexplained"]))
    report(f"identify-entries-{cell}", dict(check, convergence=done, entries=list(DIAGONAL)))
    assert done["failed"] - len(done["unexplained"]) <= done["allowed"], done
    assert not check["outside"], check
    r = check["resolution"]
    assert r["rms_z"] <= RESOLVES["diagonals"] and r["entry_rms_z"] <= RESOLVES["entry"], r
