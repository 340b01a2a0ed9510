"""What the scripts in ``sweeps/`` share: one-line errors, the parser, the solvers' names and
the many-process options. Importing it imports no JAX (so ``--help`` and bad options answer
at once); the library is imported inside the functions that need it.
"""

from __future__ import annotations

import argparse
import functools
import pathlib
import sys

# The solvers' names, as ``Numerics.method`` and saved run settings spell them (spelled out
# here so that --help needs no JAX; tests/test_bench_helpers.py holds them to the library's).
METHODS = ("rk4", "ark3", "ark4", "gark4")
Z95 = 1.959963984540054  # the two-sided 95% normal quantile


def error_line(message: str, prog: str) -> int:
    """Write one line ``PROG: error: MESSAGE`` on stderr; return exit status 2 (for a ``main``
    that returns its status)."""
    sys.stderr.write(f"{prog}: error: {message}\n")
    return 2


def fail(message: str, prog: str):
    """One line ``PROG: error: MESSAGE`` on stderr and exit status 2 (no traceback)."""
    sys.exit(error_line(message, prog))


class Parser(argparse.ArgumentParser):
    """argparse with one-line errors (``PROG: error: ...``, exit status 2), under the parser's
    own ``prog``; the description is printed as written (``RawDescriptionHelpFormatter``).
    ``kinds=True`` adds ``--import FILE.py`` (``add_import_option``), its files checked here."""

    def __init__(self, *args, kinds: bool = False, **kwargs):
        kwargs.setdefault("formatter_class", argparse.RawDescriptionHelpFormatter)
        super().__init__(*args, **kwargs)
        self.kinds = kinds
        if kinds:
            add_import_option(self)

    def parse_args(self, args=None, namespace=None):
        parsed = super().parse_args(args, namespace)
        if self.kinds:
            check_imports(parsed.imports, self.prog)
        return parsed

    def error(self, message):
        fail(message, self.prog)


def solver(method: str, *, kernel: str = "fast"):
    """The solver named ``method`` (one of ``METHODS``) with RK4's ``kernel`` (or the kernel
    the others accept)."""
    from ..._solver.ark import ARK3, ARK4
    from ..._solver.graded import GradedARK4
    from ..._solver.rk4 import RK4

    return dict(zip(METHODS, (RK4, ARK3, ARK4, GradedARK4)))[method](kernel=kernel)


def parse_cases(text: str, prog: str, example: str) -> list[tuple[str, float]]:
    """``--cases`` as ``[(controller, tau_c [N m]), ...]`` from ``"pd:0.3,imbic:1"``; one line
    (showing ``example``) and exit status 2 when it does not read so."""
    try:
        return [(c.split(":")[0], float(c.split(":")[1])) for c in text.split(",")]
    except (IndexError, ValueError):
        fail(f"--cases must look like {example}; got {text!r}", prog)


def parse_names(text: str, allowed, prog: str, option: str = "--cases") -> tuple[str, ...]:
    """A comma list of names from ``allowed`` (``"single,script"``); one line naming the allowed
    ones and exit status 2 for an unknown name or an empty list."""
    names = tuple(c.strip() for c in text.split(",") if c.strip())
    unknown = [c for c in names if c not in allowed]
    if unknown or not names:
        fail(f"{option} takes {', '.join(allowed)}; got {unknown or names}", prog)
    return names


def add_import_option(parser) -> None:
    """``--import FILE.py`` (or a module's dotted name), repeatable: a lab's own controllers and
    friction laws, loaded before the config is read so that it can name them."""
    parser.add_argument(
        "--import",
        dest="imports",
        action="append",
        default=[],
        metavar="FILE.py",
        help="a file (or module) of your own kinds (controllers, friction laws) the config names; repeatable",
    )


def check_imports(sources, prog: str) -> None:
    """One line and exit status 2 for an ``--import`` file that does not exist (before JAX)."""
    for source in sources:
        if source.endswith(".py") and not pathlib.Path(source).is_file():
            fail(f"--import {source}: no such file", prog)


def import_kinds(sources, prog: str) -> tuple[str, ...]:
    """Import each of ``sources`` (a ``.py`` file or a module's name), once per process; their
    kinds register as their classes are defined. Returns the kinds they define; one line (exit
    status 2) for a source that fails to load or defines no kind. Call it after
    ``runtime.configure()``."""
    import hashlib
    import importlib
    import importlib.util

    from ..._model.controllers import AbstractController
    from ..._model.friction import AbstractFriction

    names = []
    for source in sources:
        name = None
        try:
            if source.endswith(".py"):
                path = pathlib.Path(source).resolve()
                digest = hashlib.sha1(str(path).encode()).hexdigest()[:10]  # two kinds.py files stay two
                name = f"armimp_jax_kinds_{path.stem}_{digest}"
                if name not in sys.modules:
                    spec = importlib.util.spec_from_file_location(name, path)
                    sys.modules[name] = importlib.util.module_from_spec(spec)  # dataclasses look it up
                    spec.loader.exec_module(sys.modules[name])
                module = sys.modules[name]
            else:
                module = importlib.import_module(source)
        except Exception as err:  # a lab's file: whatever fails is the file's, named in one line
            if name is not None:
                sys.modules.pop(name, None)
            fail(f"--import {source}: {type(err).__name__}: {err}", prog)
        kinds = [
            v.kind
            for v in vars(module).values()
            if isinstance(v, type)
            and issubclass(v, (AbstractController, AbstractFriction))
            and "kind" in vars(v)
            and v.__module__ == module.__name__  # defined there, not imported into it
        ]
        if not kinds:
            fail(f"--import {source} defines no controller or friction kind (a kind names itself: kind = '...')", prog)
        names += sorted(kinds)
    return tuple(names)


def distributed_options():
    """``armimp_jax.study.runs.distributed``, for its option helpers (``add_arguments``,
    ``check_arguments``): they need no JAX (the module imports it only to start a job)."""
    from . import distributed

    return distributed


def script(prog: str):
    """Decorate a script's ``main(argv=None) -> status``: a ``ValueError`` it raises (a bad
    setting, a refused folder) becomes one line ``PROG: error: ...`` and exit status 2, with
    no traceback."""

    def wrap(main):
        @functools.wraps(main)
        def guarded(argv=None):
            try:
                return main(argv)
            except ValueError as err:
                fail(str(err), prog)

        return guarded

    return wrap
