"""How a trial is integrated, kept apart from what it simulates.

``Numerics`` is a static pytree (no leaves): passing it to a jitted function fixes the
compiled program, and two trials with different numerics cannot share a batch.
"""

from __future__ import annotations

from typing import ClassVar

from .._checks import check_choice, check_int
from .._pytree import params
from .ark import ARK3, ARK4
from .common import CHECKPOINTS, check_checkpoint
from .graded import GradedARK4
from .rk4 import RK4

# Steps per 1 ms control period of ``Numerics(substeps=None)``, per solver (why: Numerics'
# docstring; the measurements: docs/performance.md)
DEFAULT_SUBSTEPS = {"rk4": 100, "ark3": 20, "ark4": 10, "gark4": 4}
PAPER_SUBSTEPS = DEFAULT_SUBSTEPS["rk4"]  # the paper's 0.01 ms at a 1 ms period, docs/model.md section 6

SOLVERS = {"rk4": RK4, "ark3": ARK3, "ark4": ARK4, "gark4": GradedARK4}
METHODS = tuple(SOLVERS)  # the solvers' names, as saved run settings spell them


def _refusal(unknown: dict) -> str:
    """The one-line refusal of options ``Numerics`` does not take; a solver named by a string
    (``method=``, ``kernel=``) is told which solver object to pass."""
    if not unknown.keys() <= {"method", "kernel"}:
        return f"Numerics got unexpected option(s) {', '.join(sorted(unknown))}; it takes solver, substeps, checkpoint"
    try:
        solver = repr(named_solver(unknown.get("method", "rk4"), kernel=unknown.get("kernel", "fast")))
    except ValueError:
        solver = "RK4(), ARK3(), ARK4() or GradedARK4()"
    return f"Numerics takes the solver as an object, not method=/kernel=: write Numerics(solver={solver})"


def named_solver(method: str, *, kernel: str = "fast"):
    """The solver a saved ``method`` name (``"rk4"``, ``"ark3"``, ``"ark4"``, ``"gark4"``) and ``kernel`` denote."""
    check_choice("method", method, METHODS)
    return SOLVERS[method](kernel=kernel)


@params(static=("solver", "substeps", "checkpoint"))
class Numerics:
    """Integration settings of a simulation (all static; keyword arguments).

    ``Numerics()`` is ``GradedARK4()`` at 4 substeps: stable and converged at every Coulomb
    torque from 0 to 4 N m, and the cheapest such setting measured. The paper's method,
    RK4 at 100 substeps, is ``PAPER_NUMERICS``; it diverges at small Coulomb torques.

    Args:
        solver: how one control period is integrated. ``GradedARK4()`` (default;
            ``armimp_jax/_solver/graded.py``) is ``ARK4`` made cheaper: a frame frozen per
            step and short steps before each sample (``substeps + 2`` steps per period).
            ``ARK3(...)`` or ``ARK4(...)`` (additive Runge-Kutta with the LuGre bristles
            implicit, ``armimp_jax/_solver/ark.py``) are, like it, stable for every
            ``tau_c >= 0``. ``RK4(kernel=...)`` is classical Runge-Kutta, the paper's method:
            it diverges once the bristle relaxation rate ``sigma0 |v| / g`` times the step
            passes 2.8 (small Coulomb torques).
        substeps: fixed integration steps per control period (integer >= 1). ``None``
            (default): the solver's own (``DEFAULT_SUBSTEPS``), each the cheapest setting
            ``sweeps/bench_convergence.py`` found converged for it, except RK4's, the paper's:

            - ``RK4``: 100, the paper's 0.01 ms at a 1 ms period (converged at the paper's
              friction; no step it can afford is stable at small Coulomb torques);
            - ``ARK3``: 20 (``SWEEP_NUMERICS``), converged at every Coulomb torque (10 is not);
            - ``ARK4``: 10, converged at every Coulomb torque (5 is not, at small ones);
            - ``GradedARK4``: 4 (6 steps per period), converged at every Coulomb torque
              (3 is not), and the cheapest converged setting of all.
        checkpoint: what reverse mode keeps for the backward pass (forward runs are
            unaffected, gradients agree to round-off): ``"period"`` (default) one carry per
            control period, the substeps recomputed; ``"substep"`` one carry per
            substep (96 bytes each for RK4: memory grows with the record and the batch).

    The substeps are resolved when the value is built, so ``substeps`` is always an int and
    equal settings compare and hash equal however they were spelled. ``method`` and
    ``kernel`` read the solver's, and ``settings()`` gives the dictionary that saved run
    settings record. A solver named by a string (``method=``, ``kernel=``) is refused with a
    one-line ``TypeError`` that names the solver object to pass.
    """

    solver: RK4 | ARK3 | ARK4 | GradedARK4
    substeps: int
    checkpoint: str

    CHECKPOINTS: ClassVar[tuple[str, ...]] = CHECKPOINTS

    def __init__(self, *, solver=None, substeps: int | None = None, checkpoint: str = "period", **unknown):
        if unknown:
            raise TypeError(_refusal(unknown))
        solver = GradedARK4() if solver is None else solver
        if not isinstance(solver, tuple(SOLVERS.values())):
            raise ValueError(
                f"Numerics: solver must be RK4(...), ARK3(...), ARK4(...) or GradedARK4(...), got {solver!r}"
            )
        substeps = DEFAULT_SUBSTEPS[solver.method] if substeps is None else substeps
        check_checkpoint(checkpoint)
        object.__setattr__(self, "solver", solver)
        object.__setattr__(self, "substeps", check_int("substeps (steps per control period)", substeps, minimum=1))
        object.__setattr__(self, "checkpoint", checkpoint)

    @property
    def method(self) -> str:
        """The solver's name: ``"rk4"``, ``"ark3"``, ``"ark4"`` or ``"gark4"``."""
        return self.solver.method

    @property
    def kernel(self) -> str:
        """The solver's kernel: ``"fast"``, ``"reference"`` or (RK4 only) ``"grad"``."""
        return self.solver.kernel

    def settings(self) -> dict:
        """The settings as saved run settings record them: ``substeps``, ``kernel``,
        ``checkpoint``, ``method``, in that order (saved settings are compared as JSON text,
        so the order is part of a record's key)."""
        return dict(substeps=self.substeps, kernel=self.kernel, checkpoint=self.checkpoint, method=self.method)

    def __eq__(self, other):
        return isinstance(other, Numerics) and self._key() == other._key()

    def __hash__(self):
        return hash(self._key())

    def _key(self):
        return (self.solver, self.substeps, self.checkpoint)


# The paper's method: classical RK4 at 0.01 ms, which the paper reproduction and its Mhat
# tuning keep so that their numbers stay the paper's. At small Coulomb torques (0.01 N m and
# below, docs/performance.md) it diverges or is far off; use Numerics() there.
PAPER_NUMERICS = Numerics(solver=RK4(), substeps=PAPER_SUBSTEPS)

# The setting of sweeps over arbitrary friction (study.sweep.sweep's default; sweeps/sweep.py,
# friction_threshold.py, explain_claims.py, bench_fit_coverage.py): stable for every tau_c >= 0
# and within 1e-4 of a refined phi_T from 0 to 4 N m, PD and IMBIC, the four paper arms
# (sweeps/bench_convergence.py; docs/performance.md). It is ARK3 at 20 substeps although
# Numerics() is as converged and about 4x cheaper: the published sweep, claims and coverage
# results were computed with it, another setting would move them (within 1e-4), and saved
# run settings name the method and substeps, so a sweep resumes its folders only with it.
SWEEP_NUMERICS = Numerics(solver=ARK3(), substeps=20)
