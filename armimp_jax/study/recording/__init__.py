"""A lab's recordings: reading them, the Welch and model routes, pooled postures, calibration
files, their figures and reports, and a lab's day for a movement."""


def __getattr__(name: str):
    # 3.2.0's module armimp_jax.study.recording (load_recording ...) is this folder's module recording now
    if name.startswith("__"):
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    raise AttributeError(
        f"module {__name__!r} (a folder since 3.3.0) has no attribute {name!r}: import it from its module, "
        f"{__name__}.recording, or another of the folder's"
    )
