"""How a trial is integrated, kept apart from what it simulates.

``Numerics`` is a static pytree (no leaves): passing it to a jitted function fixes the
compiled program, and two trials with different numerics cannot share a batch.
"""

from __future__ import annotations

from .._checks import check_choice, check_int
from .._model.plant import CHECKPOINTS, KERNELS
from .._pytree import params

DEFAULT_SUBSTEPS = 100  # RK4 steps per 1 ms control period (h = 0.01 ms), spec section 6


METHODS = ("rk4", "ark3", "ark4")


@params(static=("substeps", "kernel", "checkpoint", "method"))
class Numerics:
    """Integration settings of a simulation (all static).

    Args:
        substeps: fixed integration steps per control period (integer >= 1; default 100, the
            paper's 0.01 ms at a 1 ms period).
        kernel: ``"fast"`` (default: ``cos/sin`` carried through the RK4 stages by exact
            small-angle rotations), ``"reference"`` (evaluated at every stage) or ``"grad"``
            (``"fast"`` arranged so that reverse-mode gradients cost less). They agree to
            round-off; see ``sweeps/bench_simulate.py`` and ``sweeps/bench_gradient.py``.
        method: ``"rk4"`` (default: classical Runge-Kutta, the paper's method) or
            ``"ark3"``/``"ark4"`` (additive Runge-Kutta in momentum form with the LuGre
            bristles implicit, ``armimp_jax/_imex.py``): stable for every ``tau_c >= 0``,
            where RK4 diverges once the bristle relaxation rate ``sigma0 |v| / g`` times the
            step passes 2.8 (small Coulomb torques). ``SWEEP_NUMERICS`` is the setting that
            ``sweeps/bench_convergence.py`` found converged across friction; the kernels
            ``"fast"``/``"reference"`` apply to it, ``"grad"`` only to RK4.
        checkpoint: what reverse mode keeps for the backward pass (forward runs are
            unaffected, gradients agree to round-off): ``"period"`` (default) one carry per
            control period, the substeps recomputed; ``"substep"`` one carry per RK4
            substep (96 bytes each: memory grows with the record and the batch).
    """

    substeps: int = DEFAULT_SUBSTEPS
    kernel: str = "fast"
    checkpoint: str = "period"
    method: str = "rk4"

    def __post_init__(self):
        object.__setattr__(
            self, "substeps", check_int("substeps (RK4 steps per control period)", self.substeps, minimum=1)
        )
        check_choice("kernel", self.kernel, KERNELS)
        check_choice("checkpoint", self.checkpoint, CHECKPOINTS)
        check_choice("method", self.method, METHODS)
        if self.method != "rk4" and self.kernel == "grad":
            raise ValueError(f"Numerics: kernel='grad' is a kernel of method='rk4', not of method={self.method!r}")

    def __eq__(self, other):
        return isinstance(other, Numerics) and self._key() == other._key()

    def __hash__(self):
        return hash(self._key())

    def _key(self):
        return (self.substeps, self.kernel, self.checkpoint, self.method)


# The setting for sweeps and tuning over arbitrary friction: stable for every tau_c >= 0
# and the cheapest measured within 1e-4 of an 8x-refined phi_T from 0 to 4 N m, PD and
# IMBIC, the four paper arms (sweeps/bench_convergence.py; table in docs/performance.md).
# Not within 1e-6 at the paper's levels: the reproduction keeps Numerics() (RK4, 100).
SWEEP_NUMERICS = Numerics(substeps=20, method="ark3")
