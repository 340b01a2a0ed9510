"""The package's layers, as docs/design.md draws them: imports point one way (down), scripts
use the public API, no module grows past 600 lines, the version is written once."""

import ast
import pathlib
import re

ROOT = pathlib.Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "armimp_jax"
# Floors from the bottom up; a module may import its own floor and those below it.
FLOORS = (
    ("_checks", "_pytree", "runtime"),
    ("_model",),
    ("_solver",),
    ("_simulate",),
    ("_estimation",),
    ("_batch",),
    ("_identification",),
    ("presets",),
    ("study",),
    ("paper",),
)
DEPRECATED_ALIASES = {"sweep", "results", "recording", "distributed", "tune"}  # old public paths


def _floor(parts: tuple[str, ...]) -> int | None:
    for i, names in enumerate(FLOORS):
        if parts and parts[0] in names:
            return i
    return None


def _modules():
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = path.relative_to(PACKAGE).with_suffix("").parts
        yield path, parts


def _imported(path: pathlib.Path, parts: tuple[str, ...]):
    """Package-relative module paths imported by ``path`` (absolute or relative imports)."""
    package = parts[:-1] if parts[-1] != "__init__" else parts[:-1]
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - (node.level - 1)]
                target = base + tuple(node.module.split(".")) if node.module else base
            elif node.module and node.module.split(".")[0] == "armimp_jax":
                target = tuple(node.module.split(".")[1:])
            else:
                continue
            names = [a.name for a in node.names]
            yield from ((target + (n,)) if not node.module and node.level else target for n in names)
        elif isinstance(node, ast.Import):
            for a in node.names:
                if a.name.split(".")[0] == "armimp_jax":
                    yield tuple(a.name.split(".")[1:])


def test_imports_point_down_the_layers():
    wrong = []
    for path, parts in _modules():
        if parts in (("__init__",),) or (len(parts) == 1 and parts[0] in DEPRECATED_ALIASES):
            continue
        mine = _floor(parts)
        assert mine is not None, f"{path.relative_to(ROOT)} is on no floor of FLOORS"
        for target in _imported(path, parts):
            theirs = _floor(target)
            if target and target[0] == "__version__":
                continue
            if theirs is None or theirs > mine:
                wrong.append(f"{path.relative_to(ROOT)} imports {'.'.join(target)}")
    assert not wrong, "imports against the layers:\n" + "\n".join(wrong)


def test_no_general_layer_imports_paper():
    for path, parts in _modules():
        if parts[0] != "paper" and parts != ("__init__",):
            assert not any(t[:1] == ("paper",) for t in _imported(path, parts)), path


def test_scripts_use_the_public_api_and_load_nothing_by_path():
    for path in sorted((ROOT / "sweeps").glob("*.py")):
        text = path.read_text()
        assert not re.search(r"armimp_jax(\.\w+)*\._\w+|from armimp_jax(\.\w+)* import _\w+", text), path
        assert "spec_from_file_location" not in text, path


def test_no_module_over_600_lines():
    for path in [*PACKAGE.rglob("*.py"), *(ROOT / "sweeps").glob("*.py")]:
        n = len(path.read_text().splitlines())
        assert n <= 600, f"{path.relative_to(ROOT)} has {n} lines"


def test_version_written_once():
    pyproject = (ROOT / "pyproject.toml").read_text()
    assert re.search(r'^version = "\d+\.\d+\.\d+"', pyproject, re.M)
    for path in PACKAGE.rglob("*.py"):
        assert not re.search(r'__version__\s*=\s*["\']', path.read_text()), path
