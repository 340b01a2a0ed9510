"""mkdocs hook (mkdocs.yml `hooks:`): a Python warning raised while the how-to guides' examples run
(markdown-exec's ```python exec="on"``` blocks) fails `mkdocs build --strict`, as an exception does.

The examples share the mkdocs process, so JAX's settings are the process's: the first page to run
calls `aj.runtime.configure()` before any JAX computation (float64, one CPU device per core), and
every later page's call finds JAX started with that device count and float64 on, and changes
nothing. A page that computed before its `configure` would get a warning from it ("came after
JAX started"): that warning, like any other an example or the library raises, is logged here as
an mkdocs warning, so the strict build fails rather than printing it and going on."""

from __future__ import annotations

import logging
import warnings

log = logging.getLogger("mkdocs.hooks.docs_exec")
_shown = warnings.showwarning


def _from_examples(category, filename: str) -> bool:
    # a RuntimeWarning or UserWarning during the build comes from an example's computation, even
    # where it points into numpy or jax; deprecations count only from the examples and the library
    return (
        issubclass(category, (RuntimeWarning, UserWarning))
        or filename.startswith("<code block")
        or "armimp_jax" in filename
    )


def _show(message, category, filename, lineno, file=None, line=None):
    if _from_examples(category, str(filename)):
        log.warning("an executed example warned: %s:%s: %s: %s", filename, lineno, category.__name__, message)
    else:
        _shown(message, category, filename, lineno, file, line)


def on_config(config):
    warnings.showwarning = _show
    return config


def on_post_build(config):
    warnings.showwarning = _shown
