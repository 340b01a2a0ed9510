"""Deprecated: moved to ``armimp_jax.study.sweep``; this name keeps old imports working."""

import warnings

from .study import sweep as _moved

warnings.warn(f"armimp_jax.sweep is deprecated; import {_moved.__name__} instead", DeprecationWarning, stacklevel=2)


def __getattr__(name):
    return getattr(_moved, name)
