"""The parametric model of a recorded impedance (docs/model.md section 13, docs/estimation.md
section 2): which acquisitions exist, and the regressors of ``K, M, B`` in the recorded ``Z``.

Shared by the fit and its result, so neither imports the other for it.
"""

from __future__ import annotations

import jax.numpy as jnp

from .._model.timing import CONTROL_PERIOD

ACQUISITIONS = ("plain", "instant", "interval_mean", "delay")
SE_METHODS = ("residual", "spectral")
ELEMENTS = ((0, 0), (0, 1), (1, 0), (1, 1))  # (output, input) of Z's elements, row-major
DEFAULT_PERIOD = CONTROL_PERIOD  # [s] the hold period of "instant" when none is given (the simulator's)


def regressors(omega, acquisition: str, period):
    """Complex regressors ``(F, 3)`` of ``K, M, B`` in the recorded ``Z`` (the delay apart), at
    angular frequencies ``omega`` [rad/s] ``(F,)`` and hold period ``period`` [s]."""
    if acquisition == "instant":
        # s (1 - exp(-s L)) / L with s = j w, written without the cancellation of 1 - exp(-j w L)
        half = 0.5 * omega * period
        c_m = -2.0 * omega * jnp.sin(half) / period * jnp.exp(-1j * half)
    else:
        c_m = -(omega**2) + 0j
    return jnp.stack([jnp.ones_like(omega) + 0j, c_m, 1j * omega], axis=-1)
