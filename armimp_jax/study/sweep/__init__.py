"""Sweeps and what they print: the sweep (``sweep``), tidy tables, figures, saved metrics, the
statistics, the friction threshold and the coverage studies."""


def __getattr__(name: str):
    # 3.2.0's module armimp_jax.study.sweep (run_sweep, SweepSettings ...) is this folder's module sweep now
    if name.startswith("__"):
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    raise AttributeError(
        f"module {__name__!r} (a folder since 3.3.0) has no attribute {name!r}: import it from its module, "
        f"{__name__}.sweep, or another of the folder's"
    )
