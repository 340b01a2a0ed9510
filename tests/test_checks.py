"""Parameter rules hold under transformations: a bad value built inside jit, vmap or grad
raises when the program runs, with the same message a concrete value gets at once. And, as
properties (hypothesis) of concrete values: any finite value inside a parameter's range is
taken as given, any outside is refused in one line naming the value and the range."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import armimp_jax as aj
from armimp_jax import paper
from armimp_jax._checks import check_int

F = aj.perturbation(jax.random.PRNGKey(0), 300, paper.perturbation_peak(1))
NUMERICS = aj.solvers.SWEEP_NUMERICS


def _final_x(trial):
    return aj.simulate(trial, F, numerics=NUMERICS).x[-1, 0]


def _imbic(mhat):
    return aj.make_trial(aj.IMBIC(mhat=mhat), arm=paper.arm(1), friction=paper.friction(1))


def test_concrete_and_traced_bad_mhat_give_the_same_rule():
    with pytest.raises(ValueError, match="IMBIC: mhat must have a positive definite symmetric part"):
        _imbic(-0.25 * np.eye(2))
    with pytest.raises(Exception, match="IMBIC: mhat must have a positive definite symmetric part"):
        jax.jit(lambda m: _final_x(_imbic(m)))(-0.25 * jnp.eye(2))


def test_one_bad_lane_of_a_vmap_raises_and_good_values_pass_unchanged():
    def run(tau_c):
        return _final_x(aj.make_trial(aj.PD(), arm=paper.arm(2), friction=aj.LuGre(tau_c=tau_c, tau_s=0.5)))

    with pytest.raises(Exception, match="LuGre: tau_c must be >= 0 N m"):
        jax.vmap(run)(jnp.array([0.1, -0.1]))
    with pytest.raises(Exception, match="LuGre: tau_s must be >= tau_c"):
        jax.vmap(run)(jnp.array([0.1, 0.7]))
    good = jax.vmap(run)(jnp.array([0.1, 0.3]))
    assert np.array_equal(good, [run(0.1), run(0.3)])


@pytest.mark.slow  # about 15 s cold: gradients through the checked paths
def test_gradients_pass_through_the_checks():
    def loss(mass_scale, *, traced):
        arm = paper.arm(1)
        mass = arm.mass * mass_scale if traced else arm.mass * 1.1
        a = aj.Arm(mass=mass, damping=arm.damping, stiffness=arm.stiffness, endpoint=arm.endpoint)
        return _final_x(aj.make_trial(aj.PD(), arm=a, friction=aj.NO_FRICTION))

    g = jax.grad(lambda s: loss(s, traced=True))(1.1)
    h = 1e-4
    fd = (loss(1.1 + h, traced=True) - loss(1.1 - h, traced=True)) / (2 * h)
    assert np.isfinite(g) and abs(g - fd) <= 1e-5 * abs(fd) + 1e-12
    assert loss(1.1, traced=True) == loss(None, traced=False)


@pytest.mark.parametrize(
    "build,rule",
    [
        (lambda v: aj.Sensors(force_noise=v), "Sensors: force_noise must be >= 0 N"),
        (lambda v: aj.Robot(shoulder_link=v), "Robot: shoulder_link must be > 0 m"),
        (lambda v: aj.PD(kp=v * jnp.eye(2)), "PD: kp must have a positive definite symmetric part"),
        (lambda v: aj.LuGre(tau_c=0.1, tau_s=0.2, v_s=v), "LuGre: v_s must be > 0 rad/s"),
        (
            lambda v: aj.Arm(mass=v * jnp.eye(2), damping=jnp.eye(2), stiffness=jnp.eye(2), endpoint=[0.0, 0.4]),
            "Arm: mass must have a positive semi-definite symmetric part",
        ),
    ],
)
def test_every_rule_of_a_parameter_holds_under_jit(build, rule):
    leaf = lambda v: sum(jnp.sum(x) for x in jax.tree.leaves(build(v)))  # noqa: E731
    with pytest.raises(Exception, match=rule):
        jax.jit(leaf)(-1.0)
    assert np.isfinite(jax.jit(leaf)(1.0))


# The properties build parameters from host values (NumPy: no JAX computation, nothing compiled);
# a fixed example sequence (derandomize) keeps the suite's result the same from run to run.
PROPERTY = settings(max_examples=100, deadline=None, derandomize=True, database=None)

# (class, field, other arguments, minimum, exclusive, unit): every range a constructor checks
RANGES = [
    (aj.CoulombViscous, "tau_c", {}, 0.0, False, " N m"),
    (aj.CoulombViscous, "viscous", dict(tau_c=0.06), 0.0, False, " N m s/rad"),
    (aj.CoulombViscous, "v_s", dict(tau_c=0.06), 0.0, True, " rad/s"),
    (aj.LuGre, "tau_s", dict(tau_c=0.0), 0.0, False, " N m"),
    (aj.LuGre, "sigma0", dict(tau_c=1.0, tau_s=1.5), 0.0, False, " N m/rad"),
    (aj.LuGre, "sigma1", dict(tau_c=1.0, tau_s=1.5), 0.0, False, " N m s/rad"),
    (aj.LuGre, "sigma2", dict(tau_c=1.0, tau_s=1.5), 0.0, False, " N m s/rad"),
    (aj.LuGre, "v_s", dict(tau_c=1.0, tau_s=1.5), 0.0, True, " rad/s"),
    (aj.Sensors, "force_noise", {}, 0.0, False, " N"),
    (aj.Sensors, "velocity_noise", {}, 0.0, False, " rad/s"),
    (aj.Sensors, "encoder_counts", {}, 1.0, False, " counts per revolution"),
    (aj.Sensors, "force_gain", {}, 0.0, True, ""),
    (aj.Sensors, "force_delay", {}, 0.0, False, " s"),
    (aj.VoluntaryForce, "std", dict(cutoff=2.0), 0.0, False, " N"),
    (aj.Robot, "shoulder_link", {}, 0.0, True, " m"),
    (aj.Robot, "elbow_link", {}, 0.0, True, " m"),
]
SCALAR = {"encoder_counts", "force_delay", "shoulder_link", "elbow_link"}  # one value; the others per joint/axis
finite = st.floats(allow_nan=False, allow_infinity=False)


def _one_line_refusal(build, message_start):
    with pytest.raises(ValueError) as err:
        build()
    text = str(err.value)
    assert text.startswith(message_start) and "\n" not in text, text
    return text


@PROPERTY
@given(case=st.sampled_from(RANGES), value=finite)
def test_any_finite_value_inside_a_range_is_taken_and_any_outside_refused_in_one_line(case, value):
    cls, name, others, minimum, exclusive, unit = case
    build = lambda: cls(**others, **{name: value})  # noqa: E731
    inside = value > minimum if exclusive else value >= minimum
    if inside:
        stored = np.asarray(getattr(build(), name))
        assert stored.dtype == np.float64 and np.all(stored == value)
        assert stored.shape == (() if name in SCALAR else (2,))
    else:
        op = ">" if exclusive else ">="
        text = _one_line_refusal(build, f"{cls.__name__}: {name} must be {op} {minimum:g}{unit}, got ")
        assert repr(float(value)) in text


@PROPERTY
@given(case=st.sampled_from([c for c in RANGES if c[1] not in SCALAR]), pair=st.lists(finite, min_size=2, max_size=2))
def test_a_per_joint_pair_is_refused_when_either_value_is_outside(case, pair):
    cls, name, others, minimum, exclusive, unit = case
    inside = [(v > minimum if exclusive else v >= minimum) for v in pair]
    build = lambda: cls(**others, **{name: pair})  # noqa: E731
    if all(inside):
        np.testing.assert_array_equal(getattr(build(), name), pair)
    else:
        _one_line_refusal(build, f"{cls.__name__}: {name} must be {'>' if exclusive else '>='} {minimum:g}{unit}")


@PROPERTY
@given(case=st.sampled_from(RANGES), value=st.sampled_from([math.nan, math.inf, -math.inf]))
def test_a_non_finite_value_is_refused_in_one_line(case, value):
    cls, name, others, *_ = case
    text = _one_line_refusal(lambda: cls(**others, **{name: value}), f"{cls.__name__}: {name}")
    assert "must be finite, got" in text and repr(value) in text


@PROPERTY
@given(value=st.integers(-(2**70), 2**70), minimum=st.integers(-5, 30))
def test_an_integer_option_is_taken_from_its_minimum_up(value, minimum):
    if value >= minimum:
        assert check_int("draws", value, minimum=minimum) == value
        if abs(value) < 2**63:
            assert check_int("draws", np.int64(value), minimum=minimum) == value
    else:
        refused = f"draws must be >= {minimum}, got {value}"
        _one_line_refusal(lambda: check_int("draws", value, minimum=minimum), refused)
    for other in (float(value), True, str(value)):
        _one_line_refusal(lambda: check_int("draws", other, minimum=minimum), f"draws must be an integer >= {minimum}")


def _symmetric_part_with_eigenvalues(e1, e2, angle, skew):
    c, s = math.cos(angle), math.sin(angle)
    r = np.array([[c, -s], [s, c]])
    return r @ np.diag([e1, e2]) @ r.T + np.array([[0.0, skew], [-skew, 0.0]])


eigenvalue = st.one_of(st.floats(1e-3, 1e3), st.floats(-1e3, -1e-3), st.just(0.0))


@PROPERTY
@given(e1=eigenvalue, e2=eigenvalue, angle=st.floats(0.0, math.pi), skew=st.floats(-1e3, 1e3))
def test_a_gain_is_taken_iff_its_symmetric_part_is_definite_and_a_mass_iff_semidefinite(e1, e2, angle, skew):
    """Whatever its antisymmetric part: PD's ``kp`` needs both eigenvalues of ``(K + K^T) / 2``
    above 0, the arm's mass both at or above 0 (a zero one's round-off within the check's 1e-12)."""
    k = _symmetric_part_with_eigenvalues(e1, e2, angle, skew)
    if min(e1, e2) > 0:
        np.testing.assert_array_equal(aj.PD(kp=k).kp, k)
    elif min(e1, e2) < 0:  # an eigenvalue of exactly 0 is the boundary: round-off decides, as it may
        _one_line_refusal(lambda: aj.PD(kp=k), "PD: kp must have a positive definite symmetric part")
    arm = lambda: aj.Arm(mass=k, damping=np.zeros((2, 2)), stiffness=np.zeros((2, 2)), endpoint=[0.0, 0.4])  # noqa: E731
    if min(e1, e2) >= 0:
        np.testing.assert_array_equal(arm().mass, k)
    else:
        _one_line_refusal(arm, "Arm: mass must have a positive semi-definite symmetric part")
