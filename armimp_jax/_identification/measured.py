"""The controller x friction-law pairs whose ``identify`` intervals a Monte Carlo of at least 50
recordings has measured (docs/identification.md, sections 6, 6b and 6c), and the warning for
any other pair: its intervals rest on the linearisation and the self-checks alone.

A pair leaves ``PAIRS_PENDING`` for ``MEASURED`` when its cell of the coverage matrix
(``armimp_bench.matrix``, run by the statistics tier) has passed at 50 recordings. A kind of a lab's
own (a controller or friction law outside the package) is never measured here."""

from __future__ import annotations

CONTROLLERS = ("pd", "imbic", "admittance")
FRICTIONS = ("lugre", "coulomb_viscous")
# (controller, friction law or "none"): where its coverage over 50 recordings is written
MEASURED = {
    ("pd", "none"): "section 6",
    ("imbic", "none"): "section 6",
    ("pd", "lugre"): "section 6",
    ("imbic", "lugre"): "sections 6 and 6b",
    ("admittance", "none"): "section 6c",
    ("admittance", "coulomb_viscous"): "section 6c (0.05 N m)",
}


def _pair(trial) -> tuple[str, str]:
    friction = type(trial.friction).kind if trial.friction.has_coulomb() else "none"
    return type(trial.controller).kind, friction


def unmeasured(trial) -> list[str]:
    """A warning where ``trial``'s controller and friction law are a pair no Monte Carlo measured."""
    controller, friction = _pair(trial)
    foreign = [
        f"a {what} of kind {kind!r} (measured: {', '.join(known)})"
        for what, kind, known in (
            ("controller", controller, CONTROLLERS),
            ("friction law", type(trial.friction).kind, FRICTIONS),
        )
        if kind not in known
    ]
    if foreign:
        named = " and ".join(foreign)
        return [
            f"these intervals have not been measured for {named}: before reporting them, check how often they hold "
            "the truth on recordings simulated with your kinds (docs/identification.md, section 6c)"
        ]
    if (controller, friction) in MEASURED:
        return []
    return [
        f"how often these intervals hold the truth under {controller} through {friction} friction has not yet been "
        "measured over 50 recordings (the coverage matrix, docs/identification.md section 6c): treat them as "
        "provisional, or check them on recordings simulated at the answer"
    ]
