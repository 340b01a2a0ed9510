"""A kind's fields are converted and checked by field converters (``aj.per_joint``, with
``minimum=``/``exclusive=``) and a rule across fields in ``__check_init__`` (issue 64): a
concrete value out of range is refused at once in one line naming the kind, the field and its
unit; a traced one (built inside ``jit``) carries the rule into the program, which raises when
it runs."""

from typing import ClassVar

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import armimp_jax as aj

# What a broken rule raises when a compiled program runs (equinox.error_if's callback): JAX
# reports it as either, with the rule's text in the message.
RUNTIME = (ValueError, jax.errors.JaxRuntimeError)


class Checked(aj.AbstractFriction):
    """A lab's viscous law with a range on each field (no ``kind``: not registered)."""

    UNITS: ClassVar[dict] = dict(b="N m s/rad", eps="rad/s")

    b: jnp.ndarray = aj.per_joint(0.01, minimum=0.0)
    eps: jnp.ndarray = aj.per_joint(1e-3, minimum=0.0, exclusive=True)

    def viscous_coefficient(self):
        return self.b

    def without_coulomb(self):
        return self

    def has_coulomb(self):
        return False


def _runs(fn, value):
    """``fn`` traces and compiles at ``value`` (no refusal at trace time) and is then run."""
    jax.jit(fn).lower(value).compile()
    return jax.block_until_ready(jax.jit(fn)(value))


def test_a_traced_stiction_below_the_coulomb_torque_raises_when_the_program_runs():
    stiction = lambda tau_c: aj.LuGre(tau_c=tau_c, tau_s=0.3).tau_s  # noqa: E731
    np.testing.assert_array_equal(_runs(stiction, 0.1), [0.3, 0.3])
    with pytest.raises(RUNTIME, match=r"LuGre: tau_s must be >= tau_c \(stiction at least the Coulomb torque\)") as err:
        _runs(stiction, 0.5)
    assert "got tau_s" not in str(err.value)  # the program's rule, not the concrete refusal


def test_a_traced_value_out_of_a_per_joint_range_raises_when_the_program_runs():
    with pytest.raises(RUNTIME, match="LuGre: v_s must be > 0 rad/s"):
        _runs(lambda v: aj.LuGre(0.1, 0.2, v_s=v).v_s, 0.0)
    with pytest.raises(RUNTIME, match="CoulombViscous: tau_c must be >= 0 N m"):
        _runs(lambda c: aj.CoulombViscous(c).tau_c, -0.01)
    with pytest.raises(RUNTIME, match="Checked: eps must be > 0 rad/s"):
        _runs(lambda e: Checked(eps=e).eps, 0.0)
    with pytest.raises(RUNTIME, match="PD: kp must have a positive definite symmetric part"):
        _runs(lambda k: aj.PD(kp=k).kp, -jnp.eye(2))
    np.testing.assert_array_equal(_runs(lambda e: Checked(eps=e).eps, 0.5), [0.5, 0.5])


@pytest.mark.parametrize(
    "build, message",
    [
        (lambda: aj.LuGre(0.1, 0.2, v_s=0.0), r"LuGre: v_s must be > 0 rad/s, got \[0.0, 0.0\]"),
        (lambda: aj.LuGre(0.1, 0.2, sigma1=(1.0, -1.0)), r"LuGre: sigma1 must be >= 0 N m s/rad, got \[1.0, -1.0\]"),
        (
            lambda: aj.LuGre(1.0, 0.5),
            r"LuGre: tau_s must be >= tau_c \(stiction at least the Coulomb torque\), "
            r"got tau_s = \[0.5, 0.5\] and tau_c = \[1.0, 1.0\] N m",
        ),
        (
            lambda: aj.CoulombViscous(0.1, viscous=-1e-3),
            r"CoulombViscous: viscous must be >= 0 N m s/rad, got \[-0.001, -0.001\]",
        ),
        (lambda: Checked(eps=0.0), r"Checked: eps must be > 0 rad/s, got \[0.0, 0.0\]"),
        (lambda: Checked(b=-1.0), r"Checked: b must be >= 0 N m s/rad, got \[-1.0, -1.0\]"),
        (lambda: Checked(b=np.nan), r"Checked: b \[N m s/rad\] must be finite, got \[nan, nan\]"),
        (
            lambda: Checked(b=(1.0, 2.0, 3.0)),
            r"Checked: b \[N m s/rad\] must be a scalar or shape \(2,\), got shape \(3,\)",
        ),
    ],
)
def test_a_concrete_value_out_of_range_is_refused_at_once_in_one_line(build, message):
    with pytest.raises(ValueError, match=f"^{message}$"):
        build()


def test_the_shipped_kinds_convert_in_field_converters_and_check_in_check_init():
    kinds = (aj.PD, aj.IMBIC, aj.Admittance, aj.LuGre, aj.CoulombViscous)
    assert not [k.__name__ for k in kinds if "__post_init__" in vars(k)]
    law = Checked(b=(0.0, 0.2))
    assert law.b.dtype == np.float64 and law.b.tolist() == [0.0, 0.2] and law.eps.tolist() == [1e-3, 1e-3]


def test_a_field_object_two_laws_share_names_each_law_and_field():
    shared = aj.per_joint(0.1, minimum=0.0)

    class First(Checked):
        UNITS: ClassVar[dict] = dict(b="N m s/rad", eps="rad/s", w="rad")
        w: jnp.ndarray = shared

    class Second(Checked):
        UNITS: ClassVar[dict] = dict(b="N m s/rad", eps="rad/s", u="N m")
        u: jnp.ndarray = shared

    with pytest.raises(ValueError, match=r"^First: w must be >= 0 rad, got"):
        First(w=-1.0)
    with pytest.raises(ValueError, match=r"^Second: u must be >= 0 N m, got"):
        Second(u=-1.0)
