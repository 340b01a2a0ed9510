"""How a trial is integrated, kept apart from what it simulates.

``Numerics`` is a static pytree (no leaves): passing it to a jitted function fixes the
compiled program, and two trials with different numerics cannot share a batch.
"""

from __future__ import annotations

import warnings
from typing import ClassVar

from .._checks import check_choice, check_int
from .._pytree import params
from .ark import ARK3, ARK4
from .common import CHECKPOINTS, check_checkpoint
from .graded import GradedARK4
from .rk4 import RK4

DEFAULT_SUBSTEPS = 100  # RK4 steps per 1 ms control period (h = 0.01 ms), docs/model.md section 6

SOLVERS = {"rk4": RK4, "ark3": ARK3, "ark4": ARK4, "gark4": GradedARK4}
METHODS = tuple(SOLVERS)  # the solvers' names, as saved run settings spell them


def named_solver(method: str, *, kernel: str = "fast"):
    """The solver a saved ``method`` name (``"rk4"``, ``"ark3"``, ``"ark4"``) and ``kernel`` denote."""
    check_choice("method", method, METHODS)
    return SOLVERS[method](kernel=kernel)


@params(static=("solver", "substeps", "checkpoint"))
class Numerics:
    """Integration settings of a simulation (all static; keyword arguments).

    Args:
        solver: how one control period is integrated: ``RK4(kernel=...)`` (default
            ``RK4()``: classical Runge-Kutta, the paper's method), ``ARK3(...)`` or
            ``ARK4(...)`` (additive Runge-Kutta with the LuGre bristles implicit,
            ``armimp_jax/_solver/ark.py``): stable for every ``tau_c >= 0``, where RK4
            diverges once the bristle relaxation rate ``sigma0 |v| / g`` times the step
            passes 2.8 (small Coulomb torques). ``SWEEP_NUMERICS`` is the setting that
            ``sweeps/bench_convergence.py`` found converged across friction.
            ``GradedARK4()`` (``armimp_jax/_solver/graded.py``) is ``ARK4`` made cheaper:
            a frame frozen per step and short steps before each sample (``substeps + 2``
            steps per period).
        substeps: fixed integration steps per control period (integer >= 1; default 100, the
            paper's 0.01 ms at a 1 ms period).
        checkpoint: what reverse mode keeps for the backward pass (forward runs are
            unaffected, gradients agree to round-off): ``"period"`` (default) one carry per
            control period, the substeps recomputed; ``"substep"`` one carry per
            substep (96 bytes each for RK4: memory grows with the record and the batch).
        method, kernel: deprecated spelling of ``solver`` (``method="ark3", kernel="fast"``
            is ``solver=ARK3(kernel="fast")``); a ``DeprecationWarning`` says so.

    ``method`` and ``kernel`` remain readable (the solver's), and ``settings()`` gives the
    dictionary that saved run settings record.
    """

    solver: RK4 | ARK3 | ARK4 | GradedARK4
    substeps: int
    checkpoint: str

    CHECKPOINTS: ClassVar[tuple[str, ...]] = CHECKPOINTS

    def __init__(
        self,
        *,
        solver=None,
        substeps: int = DEFAULT_SUBSTEPS,
        checkpoint: str = "period",
        method: str | None = None,
        kernel: str | None = None,
    ):
        if method is not None or kernel is not None:
            if solver is not None:
                raise ValueError(f"Numerics: pass solver={solver!r} or the deprecated method/kernel, not both")
            solver = named_solver("rk4" if method is None else method, kernel="fast" if kernel is None else kernel)
            warnings.warn(
                f"Numerics(method=..., kernel=...) is deprecated; write Numerics(solver={solver!r})",
                DeprecationWarning,
                stacklevel=2,
            )
        solver = RK4() if solver is None else solver
        if not isinstance(solver, tuple(SOLVERS.values())):
            raise ValueError(
                f"Numerics: solver must be RK4(...), ARK3(...), ARK4(...) or GradedARK4(...), got {solver!r}"
            )
        check_checkpoint(checkpoint)
        object.__setattr__(self, "solver", solver)
        object.__setattr__(self, "substeps", check_int("substeps (steps per control period)", substeps, minimum=1))
        object.__setattr__(self, "checkpoint", checkpoint)

    @property
    def method(self) -> str:
        """The solver's name: ``"rk4"``, ``"ark3"`` or ``"ark4"``."""
        return self.solver.method

    @property
    def kernel(self) -> str:
        """The solver's kernel: ``"fast"``, ``"reference"`` or (RK4 only) ``"grad"``."""
        return self.solver.kernel

    def settings(self) -> dict:
        """The settings as saved run settings record them (the keys and order of the former
        string fields, so that existing records still match)."""
        return dict(substeps=self.substeps, kernel=self.kernel, checkpoint=self.checkpoint, method=self.method)

    def __eq__(self, other):
        return isinstance(other, Numerics) and self._key() == other._key()

    def __hash__(self):
        return hash(self._key())

    def _key(self):
        return (self.solver, self.substeps, self.checkpoint)


# The setting for sweeps and tuning over arbitrary friction: stable for every tau_c >= 0
# and the cheapest measured within 1e-4 of an 8x-refined phi_T from 0 to 4 N m, PD and
# IMBIC, the four paper arms (sweeps/bench_convergence.py; table in docs/performance.md).
# Not within 1e-6 at the paper's levels: the reproduction keeps Numerics() (RK4, 100).
SWEEP_NUMERICS = Numerics(solver=ARK3(), substeps=20)
