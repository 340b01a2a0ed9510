"""The package's layers, as docs/design.md draws them: every import allowed by the table of
what may import what (read from the doc itself, so the two cannot drift), no import cycle,
scripts on the public API, no module over 500 lines nor function over 80, the version
written once."""

import ast
import pathlib
import re

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "armimp_jax"
DESIGN = ROOT / "docs" / "design.md"
MAX_MODULE_LINES = 500
MAX_FUNCTION_LINES = 80


def _cells(line: str) -> list[str]:
    return [c.strip() for c in line.strip().strip("|").split("|")]


def read_floors(text: str) -> dict[str, tuple[set[str], set[str]]]:
    """``{floor: (its top-level modules, the floors it may import)}`` from the table whose
    header is ``| floor | may import | must not |``: backticked names in the first cell are the
    floor's modules (the floor is named by the first); in the second, backticked names are
    floors, ``foundation`` the first row and ``every floor`` every row; the rest is notes."""
    lines = text.splitlines()
    start = next(i for i, line in enumerate(lines) if _cells(line)[:2] == ["floor", "may import"])
    rows = []
    for line in lines[start + 2 :]:
        if not line.startswith("|"):
            break
        floor_cell, may_cell = _cells(line)[:2]
        modules = re.findall(r"`(\w+)`", floor_cell)
        assert modules, f"design.md: the floor {floor_cell!r} names no module in backticks"
        rows.append((modules, re.sub(r"\([^)]*\)", "", may_cell)))
    names = [modules[0] for modules, _ in rows]
    floors = {}
    for modules, may in rows:
        allowed = set(re.findall(r"`(\w+)`", may))
        unknown = allowed - set(names)
        assert not unknown, f"design.md: {modules[0]} may import {sorted(unknown)}, which name no floor"
        if re.search(r"\bfoundation\b", may):
            allowed.add(names[0])
        if "every floor" in may:
            allowed.update(names)
        floors[modules[0]] = (set(modules), allowed | {modules[0]})
    return floors


FLOORS = read_floors(DESIGN.read_text())


def _floor_of(top: str) -> str | None:
    return next((name for name, (modules, _) in FLOORS.items() if top in modules), None)


def _modules() -> dict[tuple[str, ...], pathlib.Path]:
    """Every module of the package by its dotted parts (a package by its own name)."""
    out = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = path.relative_to(PACKAGE).with_suffix("").parts
        out[parts[:-1] if parts[-1] == "__init__" and len(parts) > 1 else parts] = path
    return out


MODULES = _modules()


def _resolve(target: tuple[str, ...]) -> tuple[str, ...]:
    """The module ``target`` names: itself, or the module holding it (a name imported from it)."""
    while target and target not in MODULES:
        target = target[:-1]
    return target or ("__init__",)


def imports(parts: tuple[str, ...]) -> set[tuple[str, ...]]:
    """The package's modules that module ``parts`` imports (anywhere in it: a lazy import
    inside a function counts)."""
    path = MODULES[parts]
    package = parts if path.name == "__init__.py" and parts != ("__init__",) else parts[:-1]
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            module = tuple(node.module.split(".")) if node.module else ()
            if node.level:
                base = package[: len(package) - (node.level - 1)] + module
            elif module[:1] == ("armimp_jax",):
                base = module[1:]
            else:
                continue
            # "from .pkg import name": the submodule pkg.name if there is one, else pkg
            found.update(
                _resolve(base + (a.name,)) if base + (a.name,) in MODULES else _resolve(base) for a in node.names
            )
        elif isinstance(node, ast.Import):
            found.update(_resolve(tuple(a.name.split(".")[1:])) for a in node.names if a.name.startswith("armimp_jax"))
    return found - {parts}


def test_the_table_is_read_and_its_floors_point_one_way():
    """Each floor may import only floors in rows above it, so the table itself has no cycle."""
    assert {"_checks", "_model", "_simulate", "_identification", "paper"} <= set().union(
        *(modules for modules, _ in FLOORS.values())
    ), FLOORS
    order = list(FLOORS)
    for name, (_, allowed) in FLOORS.items():
        if name != "paper":  # the top floor may import every floor, its own included
            later = [other for other in allowed - {name} if order.index(other) > order.index(name)]
            assert not later, f"design.md: {name} may import {later}, drawn above it"


def test_the_table_reader_reads_modules_floors_and_notes():
    text = """
| floor | may import | must not |
|---|---|---|
| foundation: `_a`, `_b` | jax | the rest |
| `_c` | foundation (a note naming `_x`) | files |
| `_d` | `_c` | |
| `top` | every floor | |

after the table
"""
    floors = read_floors(text)
    assert floors == {
        "_a": ({"_a", "_b"}, {"_a"}),
        "_c": ({"_c"}, {"_a", "_c"}),
        "_d": ({"_d"}, {"_c", "_d"}),
        "top": ({"top"}, {"_a", "_c", "_d", "top"}),
    }
    with pytest.raises(AssertionError, match="which name no floor"):
        read_floors(text.replace("| `_d` | `_c` |", "| `_d` | `_e` |"))


def test_imports_resolve_to_modules():
    assert ("_model", "timing") in imports(("_simulate",))
    assert ("_identification", "precision") in imports(("_identification", "bound"))
    assert ("_identification", "layout") in imports(("_design", "design"))


def test_every_import_is_allowed_by_the_design_table():
    wrong = []
    for parts, path in MODULES.items():
        mine = _floor_of(parts[0])
        assert mine is not None, f"{path.relative_to(ROOT)} is on no floor of the table in docs/design.md"
        for target in imports(parts):
            theirs = _floor_of(target[0])
            if theirs not in FLOORS[mine][1]:
                wrong.append(f"{path.relative_to(ROOT)} ({mine}) imports {'.'.join(target)} ({theirs})")
    assert not wrong, "imports the table in docs/design.md does not allow:\n" + "\n".join(wrong)


def find_cycles(graph: dict) -> list[list]:
    """The strongly connected components of ``graph`` (``{node: targets}``) with more than one
    node, or a node importing itself (Tarjan's algorithm, iterative)."""
    index, low, stack, on_stack, cycles, counter = {}, {}, [], set(), [], [0]
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(sorted(graph.get(root, ()))))]
        index[root] = low[root] = counter[0]
        counter[0] += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            node, targets = work[-1]
            target = next(targets, None)
            if target is not None:
                if target not in index:
                    index[target] = low[target] = counter[0]
                    counter[0] += 1
                    stack.append(target)
                    on_stack.add(target)
                    work.append((target, iter(sorted(graph.get(target, ())))))
                elif target in on_stack:
                    low[node] = min(low[node], index[target])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                if len(component) > 1 or node in graph.get(node, ()):
                    cycles.append(sorted(component))
    return cycles


def test_find_cycles_finds_direct_and_indirect_cycles_only():
    assert find_cycles({"a": {"b"}, "b": {"a"}, "c": {"a"}}) == [["a", "b"]]
    assert find_cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": set()}) == [["a", "b", "c"]]
    assert find_cycles({"a": {"a"}}) == [["a"]]
    assert find_cycles({"a": {"b", "c"}, "b": {"c"}, "c": set()}) == []


def test_no_import_cycle():
    cycles = find_cycles({parts: imports(parts) for parts in MODULES})
    assert not cycles, "modules that import each other:\n" + "\n".join(
        " <-> ".join(".".join(m) for m in cycle) for cycle in cycles
    )


STUDY_FOLDERS = ("runs", "schema", "sweep", "recording", "design")  # docs/design.md: none imports a later one


def test_study_s_folders_import_only_earlier_ones():
    folders = {parts[1] for parts in MODULES if parts[0] == "study" and len(parts) > 2}
    assert folders == set(STUDY_FOLDERS), "study/'s folders differ from docs/design.md's"
    assert not [p for p in MODULES if p[:1] == ("study",) and len(p) == 2 and p[1] not in STUDY_FOLDERS], "outside"
    for parts in MODULES:
        if parts[0] == "study" and len(parts) > 2:
            later = [
                t
                for t in imports(parts)
                if t[0] == "study"
                and len(t) > 1
                and t[1] in STUDY_FOLDERS
                and STUDY_FOLDERS.index(t[1]) > STUDY_FOLDERS.index(parts[1])
            ]
            assert not later, f"{'.'.join(parts)} imports the later {['.'.join(t) for t in later]}"


def test_no_general_layer_imports_paper():
    for parts in MODULES:
        if _floor_of(parts[0]) != "paper":
            assert not any(t[:1] == ("paper",) for t in imports(parts)), parts


def test_the_package_does_not_import_the_measurement_harness():
    # sweeps/armimp_bench is the project's own, not installed: the library must stand without it
    for path in sorted(PACKAGE.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else []
            names += [node.module or ""] if isinstance(node, ast.ImportFrom) else []
            assert not [n for n in names if n.split(".")[0] == "armimp_bench"], path.relative_to(ROOT)
    assert not (PACKAGE / "bench").exists()


def test_scripts_use_the_public_api_and_load_nothing_by_path():
    for path in sorted((ROOT / "sweeps").glob("*.py")):
        text = path.read_text()
        assert not re.search(r"armimp_jax(\.\w+)*\._\w+|from armimp_jax(\.\w+)* import _\w+", text), path
        assert "spec_from_file_location" not in text, path


SOURCES = [*sorted(PACKAGE.rglob("*.py")), *sorted((ROOT / "sweeps").rglob("*.py"))]


@pytest.mark.parametrize("path", SOURCES, ids=lambda p: str(p.relative_to(ROOT)))
def test_no_module_over_500_lines_nor_function_over_80(path):
    text = path.read_text()
    n = len(text.splitlines())
    assert n <= MAX_MODULE_LINES, f"{path.relative_to(ROOT)} has {n} lines (at most {MAX_MODULE_LINES})"
    long = [
        f"{node.name} (line {node.lineno}): {node.end_lineno - node.lineno + 1} lines"
        for node in ast.walk(ast.parse(text))
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef))
        and node.end_lineno - node.lineno + 1 > MAX_FUNCTION_LINES
    ]
    assert not long, f"{path.relative_to(ROOT)}: functions over {MAX_FUNCTION_LINES} lines: {', '.join(long)}"


def test_the_line_limits_are_the_ones_design_md_states():
    text = DESIGN.read_text()
    assert f"no module over {MAX_MODULE_LINES} lines, no function over {MAX_FUNCTION_LINES} lines" in text


def test_version_written_once():
    pyproject = (ROOT / "pyproject.toml").read_text()
    assert re.search(r'^version = "\d+\.\d+\.\d+"', pyproject, re.M)
    for path in PACKAGE.rglob("*.py"):
        assert not re.search(r'__version__\s*=\s*["\']', path.read_text()), path
