"""What the integrators share: the checkpoint modes of a period and the small-angle
rotation that carries ``cos/sin`` of the joint angles through the stages of a step."""

from __future__ import annotations

import jax

from .._checks import check_choice
from .._model.plant import Trig

# How the simulation checkpoints a control period for reverse mode (``Numerics.checkpoint``).
CHECKPOINTS = ("period", "substep")


def check_checkpoint(checkpoint: str) -> None:
    check_choice("checkpoint", checkpoint, CHECKPOINTS)


def check_kernel(solver) -> None:
    """Refuse a kernel the solver does not have, naming the solver and its kernels."""
    if isinstance(solver.kernel, bool) or solver.kernel not in solver.KERNELS:
        allowed = ", ".join(map(repr, solver.KERNELS))
        raise ValueError(f"{type(solver).__name__}: unknown kernel {solver.kernel!r}; allowed: {allowed}")


@jax.custom_jvp
def _small_angle_cos_sin(d):
    d2 = d * d
    return 1.0 - d2 * (0.5 - d2 * (1.0 / 24 - d2 / 720)), d * (1.0 - d2 * (1.0 / 6 - d2 * (1.0 / 120 - d2 / 5040)))


@_small_angle_cos_sin.defjvp
def _small_angle_cos_sin_jvp(primals, tangents):
    # The derivatives of cos and sin, not of the truncated series (they differ by
    # d^7/5040, far below round-off): 4% fewer operations in the backward loop body.
    (d,), (t,) = primals, tangents
    c, s = _small_angle_cos_sin(d)
    return (c, s), (-s * t, c * t)


def rotate(t: Trig, d1, d2) -> Trig:
    """``Trig`` of the angles advanced by ``d1``, ``d2`` [rad], by the angle-addition formulas
    with Taylor ``cos/sin`` of the increments (to ``d^6``, ``d^7``: exact to round-off for
    ``|d| < 0.03`` rad; an RK4 substep moves ~1e-6 rad). No transcendental is evaluated."""

    cd1, sd1 = _small_angle_cos_sin(d1)
    cd2, sd2 = _small_angle_cos_sin(d2)
    return Trig(t.c1 * cd1 - t.s1 * sd1, t.s1 * cd1 + t.c1 * sd1, t.c2 * cd2 - t.s2 * sd2, t.s2 * cd2 + t.c2 * sd2)
