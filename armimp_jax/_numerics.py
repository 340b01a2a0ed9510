"""How a trial is integrated, kept apart from what it simulates.

``Numerics`` is a static pytree (no leaves): passing it to a jitted function fixes the
compiled program, and two trials with different numerics cannot share a batch.
"""

from __future__ import annotations

from ._checks import check_choice, check_int
from ._plant import CHECKPOINTS, KERNELS
from ._pytree import params

DEFAULT_SUBSTEPS = 100  # RK4 steps per 1 ms control period (h = 0.01 ms), spec section 6


@params(static=("substeps", "kernel", "checkpoint"))
class Numerics:
    """Integration settings of a simulation (all static).

    Args:
        substeps: fixed RK4 steps per control period (integer >= 1; default 100, the
            paper's 0.01 ms at a 1 ms period).
        kernel: ``"fast"`` (default: ``cos/sin`` carried through the RK4 stages by exact
            small-angle rotations), ``"reference"`` (evaluated at every stage) or ``"grad"``
            (``"fast"`` arranged so that reverse-mode gradients cost less). They agree to
            round-off; see ``sweeps/bench_simulate.py`` and ``sweeps/bench_gradient.py``.
        checkpoint: what reverse mode keeps for the backward pass (forward runs are
            unaffected, gradients agree to round-off): ``"period"`` (default) one carry per
            control period, the substeps recomputed; ``"substep"`` one carry per RK4
            substep (96 bytes each: memory grows with the record and the batch).
    """

    substeps: int = DEFAULT_SUBSTEPS
    kernel: str = "fast"
    checkpoint: str = "period"

    def __post_init__(self):
        object.__setattr__(
            self, "substeps", check_int("substeps (RK4 steps per control period)", self.substeps, minimum=1)
        )
        check_choice("kernel", self.kernel, KERNELS)
        check_choice("checkpoint", self.checkpoint, CHECKPOINTS)

    def __eq__(self, other):
        return isinstance(other, Numerics) and self._key() == other._key()

    def __hash__(self):
        return hash(self._key())

    def _key(self):
        return (self.substeps, self.kernel, self.checkpoint)
