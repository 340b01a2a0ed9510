"""How long to record (``record.py``): one convention, +-X at 95%, for the bound's record, the
record through the friction and a design's, in closed form; bad inputs refused in one line
before any simulation; the printout's labels; and (slow) the answers against ``crlb`` and
``predict_se`` themselves."""

import warnings

import jax
import numpy as np
import pytest
import scipy.stats

import armimp_jax as aj
from armimp_jax import paper
from armimp_jax._design import record
from armimp_jax._design.record import (
    _check_record,
    _design_relative,
    _statistic,
    _worst_arm,
    design_lines,
)
from armimp_jax._identification import layout as lay
from armimp_jax._identification.precision import Z95, quantile, record_seconds

ARM = ("arm.mass", "arm.damping", "arm.stiffness")
DIAGONALS = tuple(f"{n}[{i},{i}]" for n in ARM for i in range(2))
NOISE = dict(sensors=aj.Sensors(force_noise=0.05, encoder_counts=2**18), voluntary=aj.VoluntaryForce(0.3, 2.0))


def _trial(controller=None, friction=None, location=2):
    friction = aj.LuGre(1.0, 1.5) if friction is None else friction
    return aj.make_trial(controller or aj.IMBIC(), arm=paper.arm(location), friction=friction, **NOISE)


def _bound(rel: dict, seconds: float = 20.0) -> aj.results.Bound:
    """A ``Bound`` whose entries have the relative SEs ``rel`` (label: value; the rest 0.5): the
    host-side record arithmetic needs nothing else."""
    labels = [f"{n}[{i},{j}]" for n in ARM for i in range(2) for j in range(2)]
    flat = np.array([rel.get(label, 0.5) for label in labels])
    mats = {n: flat[4 * k : 4 * k + 4].reshape(2, 2) for k, n in enumerate(ARM)}
    nan = np.full((12, 12), np.nan)
    return aj.results.Bound(
        se=mats, values={n: np.ones((2, 2)) for n in ARM}, relative_se=mats, covariance=nan, information=nan,
        labels=labels, seconds=seconds, reference="the trial's loop", near_linear=True, nonlinearity=np.zeros(4),
        spectral_radius=0.5, message="",
    )  # fmt: skip


def test_one_convention_the_half_width_at_95_percent_in_closed_form():
    """+-X at 95% is X = 1.96 SE / |value|: the record is ((1.96 rel_SE) / X)^2 times the record the
    SE was had at, for the bound and for every other answer (one formula); another level takes its
    own quantile; the deprecated relative-SE target is the same goal at 1.96 times it."""
    rel, seconds = 0.04, 20.0
    assert Z95 == pytest.approx(scipy.stats.norm.ppf(0.975), rel=1e-15)
    assert record_seconds(seconds, rel, 0.1) == pytest.approx(seconds * (1.959963984540054 * rel / 0.1) ** 2)
    assert record_seconds(seconds, rel, 0.05) == pytest.approx(4 * record_seconds(seconds, rel, 0.1), rel=1e-14)
    z99 = scipy.stats.norm.ppf(0.995)
    assert quantile(0.99) == pytest.approx(z99, rel=1e-12)
    assert record_seconds(seconds, rel, 0.1, level=0.99) == pytest.approx(seconds * (z99 * rel / 0.1) ** 2, rel=1e-12)
    # a record where the SE is +-X at 95% exactly: 1.96 rel_SE = X, so the record is the one given
    assert record_seconds(seconds, 0.1 / Z95, 0.1) == pytest.approx(seconds, rel=1e-14)
    b = _bound({"arm.stiffness[0,0]": rel, "arm.mass[1,1]": 0.02}, seconds)
    assert b.record_for(0.1) == pytest.approx(record_seconds(seconds, 0.5, 0.1), rel=1e-14)  # the worst diagonal
    assert b.record_for(0.1, entries=["arm.stiffness[0,0]"]) == pytest.approx(seconds * (Z95 * rel / 0.1) ** 2)
    # record_for(target=relative SE), deprecated: the same goal as precision = 1.96 SE at 95%
    trial, f = _trial(), np.ones((3000, 2))
    with pytest.warns(DeprecationWarning, match=r"record_for\(target=.*goes in armimp_jax 3.0: pass precision="):
        _, widths = _check_record(trial, f, ARM, 0.1, 0.95, None, 64, False, {"arm.stiffness[1,1]": 0.05})
    assert widths == {"arm.stiffness[1,1]": pytest.approx(Z95 * 0.05, rel=1e-15)}
    _, default = _check_record(trial, f, ARM, 0.1, 0.95, None, 64, False, None)
    assert tuple(default) == DIAGONALS and set(default.values()) == {0.1}  # a design's default targets


def test_bad_inputs_are_refused_in_one_line_before_any_simulation(monkeypatch):
    def simulated(*args, **kwargs):
        raise AssertionError("a bad input reached a simulation")

    for name in ("crlb", "predict_se", "is_near_linear"):
        monkeypatch.setattr(record, name, simulated)
    trial, f = _trial(), np.ones((3000, 2))
    cases = [
        (dict(precision=0.0), r"record_for: precision must lie in \(0, 1\) \(a relative half-width: 0.1 is \+-10%\)"),
        (dict(precision=10), r"precision must lie in \(0, 1\).*got 10"),
        (dict(precision={"arm.mass[0,0]": 1.5}), r"precision must lie in \(0, 1\).*got 1.5"),
        (dict(level=95), r"record_for: level must lie in \(0, 1\) \(0.95: 95% intervals\), got 95"),
        (dict(entries=["arm.mass[3,3]"]), r"record_for: unknown entry \['arm.mass\[3,3\]'\]; the free parameters'"),
        (dict(entries=["arm.mass[0,0]"], precision={"arm.mass[0,0]": 0.1}), "give entries or a precision per entry"),
        (dict(draws=4), "draws must be >= 8, got 4"),
        (dict(check="yes"), "record_for: check must be True or False, got 'yes'"),
        (dict(statistic="whittle"), "unknown statistic 'whittle'; allowed: 'auto', 'efficient', 'welch'"),
        (dict(design="d"), "record_for: design must be aj.design's answer, got str"),
        (dict(free=("arm.inertia",)), "unknown parameter 'arm.inertia'"),
    ]
    for kwargs, message in cases:
        kwargs = {"free": ARM, **kwargs}
        with pytest.raises(ValueError, match=message) as err:
            aj.record_for(trial, f, **kwargs)
        assert "\n" not in str(err.value), str(err.value)
    with pytest.raises(ValueError, match=r"record_for: f must have shape \(N, 2\), got \(3000, 3\)"):
        aj.record_for(trial, np.ones((3000, 3)), free=ARM)
    with pytest.raises(ValueError, match="record_for: the trial has no noise"):
        aj.record_for(aj.make_trial(aj.IMBIC(), arm=paper.arm(2), friction=aj.NO_FRICTION), f, free=ARM)
    eye = np.eye(2)
    arm = aj.Arm(mass=eye, damping=10 * eye, stiffness=100 * eye, endpoint=paper.arm(2).endpoint)
    diagonal = aj.make_trial(aj.PD(), arm=arm, friction=aj.NO_FRICTION, **NOISE)
    with pytest.raises(ValueError, match=r"record_for: arm.mass\[0,1\] is 0 in the trial.*leave it out of entries"):
        aj.record_for(diagonal, f, free=ARM, entries=["arm.mass[0,1]"])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        with pytest.raises(ValueError, match=r"record_for: target relative SEs must lie in \(0, 1\)"):
            aj.record_for(trial, f, free=ARM, target={"arm.mass[0,0]": 2.0})
    # identify's rule, decided before any simulation: no free arm matrix, no efficient statistic
    assert _statistic(trial, f, lay.make_layout(("friction.tau_c",)), "efficient", None) == "welch"


def _length(**kw) -> aj.results.RecordLength:
    entries = ("arm.mass[0,0]", "arm.stiffness[0,0]")
    base = dict(
        entries=entries, precision=dict.fromkeys(entries, 0.1), level=0.95, seconds=20.0,
        bound={"arm.mass[0,0]": 12.0, "arm.stiffness[0,0]": 30.0},
        predicted={"arm.mass[0,0]": 45.0, "arm.stiffness[0,0]": 60.0},
        design={"arm.mass[0,0]": 90.0, "arm.stiffness[0,0]": 162.0}, design_basis="predict_se",
        statistic="efficient", draws=64, friction=True, period=1e-3,
    )  # fmt: skip
    return aj.results.RecordLength(**{**base, **kw})


def test_the_printout_labels_each_answer_and_says_which_to_plan_on():
    r = _length()
    text = r.summary()
    lines = text.splitlines()
    assert lines[0].startswith("How long to record for +-10% at 95% (the relative half-width of the 95% interval)")
    for head in ("bound: floor, no friction", "predict_se, through the friction", "design: worst arm (predict_se)"):
        assert head in lines[1], (head, lines[1])
    longest = next(line for line in lines if line.startswith("longest")).split()
    assert longest[1:] == ["0.5", "min", "1", "min", "2.7", "min"]  # 30 s, 60 s, 162 s
    assert "plan on 1 min (60 s): identify's own standard errors (predict_se, the efficient statistic, 64 draws" in text
    assert "predict_se needs 2 times it, the cost of the joints' Coulomb friction" in text
    assert "the design's 2.7 min is its own answer" in text and "the record if you run the designed" in text
    assert r.record_s == pytest.approx(60.0) and r.longest("bound") == 30.0
    plain = _length(friction=False, design=None, bound=dict.fromkeys(r.entries, float("nan")), notes=("no bound: x",))
    text = plain.summary()
    assert "predict_se (identify)" in text and "design:" not in text and "note: no bound: x" in text
    assert next(line for line in text.splitlines() if line.startswith("longest")).split()[1] == "-"
    checked = _length(check={"arm.mass[0,0]": 0.08, "arm.stiffness[0,0]": 0.11})
    assert "checked at 60 s: predict_se gives +-11% on arm.stiffness[0,0] (asked +-10%" in checked.summary()
    with pytest.warns(DeprecationWarning, match=r"record_for\(...\)\['record_s'\] is deprecated"):
        assert r["record_s"] == r.record_s
    with pytest.warns(DeprecationWarning):
        assert checked["check"]["arm.mass[0,0]"] == pytest.approx(0.08 / Z95)  # the old relative SE


def test_a_designs_record_per_arm_in_the_same_convention():
    """A calibrated bound design's own answer: the bound's relative SEs times its friction ratios,
    per arm; the design's column is the worst arm; ``design_lines`` prints both rows labelled."""
    targets = ("arm.mass[0,0]", "arm.stiffness[0,0]")
    trials = [_trial(location=1), _trial(location=2)]
    bounds = [_bound({"arm.mass[0,0]": 0.02, "arm.stiffness[0,0]": 0.04}), _bound({"arm.stiffness[0,0]": 0.03})]
    ratio = np.array([[2.0, 1.5], [1.0, 3.0]])
    d = aj.results.BoundDesign(
        family=None, signal=np.zeros((20_000, 2)), start_signal=None, trials=trials, controller={}, bounds=bounds,
        start_bounds=bounds, minutes=[], start_minutes=[], criterion_before=0.0, criterion_after=0.0, trace=[],
        achieved={}, time_s=0.0, predicted_minutes=[], friction_ratio=ratio, targets=targets,
    )  # fmt: skip
    per_arm, seconds, basis = _design_relative(d, targets, "record_for")
    assert seconds == 20.0 and basis == "predict_se"
    assert per_arm[0] == pytest.approx({"arm.mass[0,0]": 0.04, "arm.stiffness[0,0]": 0.06})
    assert per_arm[1] == pytest.approx({"arm.mass[0,0]": 0.5, "arm.stiffness[0,0]": 0.09})
    worst = _worst_arm(lambda rel, at: {e: record_seconds(at, rel[e], 0.1) for e in targets}, (per_arm, seconds, basis))
    expected = {"arm.mass[0,0]": record_seconds(20.0, 0.5, 0.1), "arm.stiffness[0,0]": record_seconds(20.0, 0.09, 0.1)}
    assert worst == pytest.approx(expected, rel=1e-12)
    with pytest.raises(ValueError, match=r"the design predicted its targets .*, not arm.damping\[0,0\]"):
        _design_relative(d, ("arm.damping[0,0]",), "record_for")
    lines = design_lines(d, 0.1, labels=["arm 1", "arm 2"], written_s=123.0)
    assert "bound: floor, no friction" in lines[1] and "predict_se, through the friction" in lines[1]
    worst = record_seconds(20.0, 0.5, 0.1) / 60  # arm 2's mass through the friction
    assert lines[-2] == f"plan on {worst:.3g} min (predict_se's worst arm: identify's own standard errors)"
    assert lines[-1] == "the record written: 123 s (2.05 min)"
    bound_only = d._replace(friction_ratio=None)
    assert "predict_se" not in design_lines(bound_only, 0.1)[1]
    assert "calibrate to see it" in design_lines(bound_only, 0.1)[-1]


@pytest.mark.slow  # 644 s cold on 2 cores shared at load 11-15: the bound and five short predictions
def test_record_for_agrees_with_crlb_and_predict_se_in_closed_form():
    """IMBIC through 1 N m of LuGre friction: the bound's row is ``crlb``'s relative SEs carried by
    the closed form, the friction's row ``predict_se``'s (same draws); the deprecated target gives
    the same seconds; the check at a 6 s answer meets its precision within its draws' noise."""
    trial = _trial()
    f = aj.perturbation(jax.random.key(3), 3000, paper.perturbation_peak(1))
    key = jax.random.key(4)
    out = aj.record_for(trial, f, free=ARM, precision=0.1, draws=16, key=key)
    assert out.entries == DIAGONALS and out.statistic == "efficient" and out.friction and out.seconds == 3.0
    bound = aj.crlb(trial, f, free=ARM).relative(DIAGONALS)
    pred = aj.predict_se(trial, f, free=ARM, statistic="efficient", draws=16, key=key)
    layout = lay.make_layout(ARM)
    values = dict(
        zip(pred.labels, np.abs(np.asarray(lay.natural(layout, lay.pack(layout, trial), trial))), strict=True)
    )
    se = dict(zip(pred.labels, np.sqrt(np.diag(np.asarray(pred.covariance))), strict=True))
    for e in DIAGONALS:
        assert out.bound[e] == pytest.approx(3.0 * (Z95 * bound[e] / 0.1) ** 2, rel=1e-9), e
        assert out.predicted[e] == pytest.approx(3.0 * (Z95 * se[e] / values[e] / 0.1) ** 2, rel=1e-9), e
    assert out.longest("predicted") > out.longest("bound")  # the friction costs information the bound counts
    with pytest.warns(DeprecationWarning):
        old = aj.record_for(trial, f, free=ARM, target={"arm.stiffness[0,0]": 0.1 / Z95}, draws=16, key=key)
    assert old.predicted["arm.stiffness[0,0]"] == pytest.approx(out.predicted["arm.stiffness[0,0]"], rel=1e-9)
    # the check, on the masses at the precision that asks for 6 s: +-X there within 16 draws' noise (+-18% in SE)
    e = "arm.mass[1,1]"
    widths = {e: 0.1 * np.sqrt(out.predicted[e] / 6.0)}
    checked = aj.record_for(trial, f, free=ARM, precision=widths, draws=16, key=key, check=True)
    assert checked.record_s == pytest.approx(6.0, abs=1e-3)
    assert widths[e] / 1.6 < checked.check[e] < 1.6 * widths[e], (checked.check, widths)
    assert "plan on" in out.summary() and "checked at 6 s" in checked.summary()


@pytest.mark.slow  # 838 s cold on 2 cores shared at load 11-15: stick-slip, no bound; three predictions
def test_record_for_through_stick_slip_answers_without_a_bound():
    trial = _trial(aj.PD(), aj.LuGre(0.3, 0.45))
    f = aj.perturbation(jax.random.key(5), 4000, 10.0)
    precision = {"arm.stiffness[1,1]": 0.1, "arm.mass[0,0]": 0.02}
    out = aj.record_for(trial, f, free=ARM, precision=precision, draws=32, check=True)
    assert out.statistic == "welch"  # identify's choice through stick-slip (PD, 0.3 N m)
    assert all(np.isnan(v) for v in out.bound.values()) and any("no bound" in n for n in out.notes)
    assert out.record_s == pytest.approx(max(out.predicted.values()), abs=1e-3)
    for e, goal in precision.items():  # the check at that length: met within the predictions' own noise
        assert out.check[e] <= 1.2 * goal * np.sqrt(out.predicted[e] / out.record_s), (e, out)
    # a record past an hour is answered without the check, which would simulate it
    far = aj.record_for(trial, f, free=ARM, precision={"arm.mass[0,0]": 1e-4}, draws=32, check=True)
    assert far.record_s > 3600 and far.check is None and any("no check past" in n for n in far.notes)
