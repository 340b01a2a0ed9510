"""What the scripts share before they import JAX (kept free of it so ``--help`` stays fast)."""

from __future__ import annotations

import argparse
import importlib.util
import pathlib
import sys


def fail(message: str, prog: str):
    """One line ``PROG: error: MESSAGE`` on stderr and exit status 2 (no traceback)."""
    sys.stderr.write(f"{prog}: error: {message}\n")
    sys.exit(2)


class Parser(argparse.ArgumentParser):
    """argparse with one-line errors (``PROG: error: ...``, exit status 2), under the
    parser's own ``prog``."""

    def error(self, message):
        fail(message, self.prog)


def distributed_options():
    """``armimp_jax/study/distributed.py`` loaded on its own, for its option helpers: they need no
    JAX, and importing the package would start it."""
    package = importlib.util.find_spec("armimp_jax")
    path = pathlib.Path(package.submodule_search_locations[0]) / "study" / "distributed.py"
    spec = importlib.util.spec_from_file_location("_armimp_jax_distributed_options", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module
