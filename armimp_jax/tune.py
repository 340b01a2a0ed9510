"""Deprecated: moved to ``armimp_jax.study.tune``; this name keeps old imports working."""

import warnings

from .study import tune as _moved

warnings.warn(f"armimp_jax.tune is deprecated; import {_moved.__name__} instead", DeprecationWarning, stacklevel=2)


def __getattr__(name):
    return getattr(_moved, name)
