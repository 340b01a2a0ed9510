"""The kinds whose ``identify`` intervals the coverage matrix measures (``bench.matrix``, run by
the statistics tier: every controller x friction law below, 50 recordings a cell), and the
warning for a kind outside them: its intervals rest on the linearisation and the self-checks
alone, with no Monte Carlo of their coverage behind them."""

from __future__ import annotations

CONTROLLERS = ("pd", "imbic", "admittance")
FRICTIONS = ("lugre", "coulomb_viscous")


def unmeasured(trial) -> list[str]:
    """A warning where ``trial``'s controller or friction law is a kind the matrix does not measure."""
    kinds = [
        (what, kind, measured)
        for what, kind, measured in (
            ("controller", type(trial.controller).kind, CONTROLLERS),
            ("friction law", type(trial.friction).kind, FRICTIONS),
        )
        if kind not in measured
    ]
    if not kinds:
        return []
    named = " and ".join(f"a {what} of kind {kind!r} (measured: {', '.join(m)})" for what, kind, m in kinds)
    return [
        f"these intervals have not been measured for {named}: before reporting them, check how often they hold "
        "the truth on recordings simulated with your kinds (docs/identification.md, section 6c)"
    ]
