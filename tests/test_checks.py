"""Parameter rules hold under transformations: a bad value built inside jit, vmap or grad
raises when the program runs, with the same message a concrete value gets at once."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import armimp_jax as aj
from armimp_jax import paper

F = aj.perturbation(jax.random.PRNGKey(0), 300, paper.perturbation_peak(1))
NUMERICS = aj.SWEEP_NUMERICS


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
