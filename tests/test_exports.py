"""The public names: one lazy table per face (``armimp_jax``, ``armimp_jax.study``), and
``__all__``, the table and the lists in docs/design.md ("The public names") agree; every
name loads from the module the table names; the top level holds at most 40 names, the rest
in namespaces, a type checker's imports name every one, and an old name says where it went."""

import ast
import importlib
import pathlib
import re

import pytest

import armimp_jax
import armimp_jax.study

ROOT = pathlib.Path(__file__).resolve().parents[1]
FACES = {"armimp_jax": (armimp_jax, {"runtime"}), "armimp_jax.study": (armimp_jax.study, set())}


def _documented() -> dict[str, set[str]]:
    text = (ROOT / "docs" / "design.md").read_text()
    section = text[text.index("## The public names") :]
    blocks = re.findall(r"^`([\w.]+)`[^\n]*:\n\n```text\n(.*?)```", section, flags=re.M | re.S)
    return {name: set(body.split()) for name, body in blocks}


@pytest.mark.parametrize("face", FACES)
def test_all_is_the_lazy_table_and_the_docs_list(face):
    module, eager = FACES[face]
    table = set(module._EXPORTS)
    assert set(module.__all__) == table | eager
    assert len(module.__all__) == len(set(module.__all__))
    assert _documented()[face] == set(module.__all__), "docs/design.md's list differs from __all__"
    assert set(dir(module)) >= set(module.__all__)


@pytest.mark.parametrize("face", FACES)
def test_every_name_loads_from_the_module_the_table_names(face):
    module, _ = FACES[face]
    for name, where in module._EXPORTS.items():
        relative = where if where.startswith(".") else f".{where}"
        source = importlib.import_module(relative, module.__name__)
        assert getattr(module, name) is getattr(source, name), name
    with pytest.raises(AttributeError, match="has no attribute 'no_such_name'"):
        module.no_such_name  # noqa: B018


NAMESPACES = [n for n in armimp_jax._NAMESPACES if n not in ("presets", "paper", "study")]


def test_the_top_level_holds_at_most_40_names_and_the_rest_in_namespaces():
    assert len(armimp_jax.__all__) <= 40
    documented = _documented()
    for ns in NAMESPACES:
        module = getattr(armimp_jax, ns)  # loaded on first use
        assert documented[f"armimp_jax.{ns}"] == set(module.__all__), ns
        assert not set(module.__all__) & set(armimp_jax.__all__), ns
    placed = {n for ns in NAMESPACES for n in getattr(armimp_jax, ns).__all__}
    assert set(armimp_jax._MOVED) <= placed | set(armimp_jax.presets.__dict__)


def test_an_old_name_says_where_it_went_in_one_line():
    for name, ns in armimp_jax._MOVED.items():
        with pytest.raises(AttributeError) as err:
            getattr(armimp_jax, name)
        assert str(err.value) == f"armimp_jax.{name} is now armimp_jax.{ns}.{name}"
        assert getattr(getattr(armimp_jax, ns), name) is not None
    with pytest.raises(AttributeError, match=r"armimp_jax.lugre is gone: use LuGre\(...\).joint\(i\).torque_and_rate"):
        armimp_jax.lugre  # noqa: B018


def test_a_type_checker_reads_every_public_name_from_its_module():
    # the TYPE_CHECKING block of armimp_jax/__init__.py imports each name of the lazy table from
    # the module the table names, and every namespace
    tree = ast.parse((ROOT / "armimp_jax" / "__init__.py").read_text())
    block = next(n for n in tree.body if isinstance(n, ast.If) and getattr(n.test, "id", "") == "TYPE_CHECKING")
    seen = {}
    for node in block.body:
        for alias in node.names:
            assert alias.asname == alias.name  # an explicit re-export
            seen[alias.name] = "." * node.level + (node.module or "")
    for name, where in armimp_jax._EXPORTS.items():
        assert seen.get(name) == where, name
    assert all(seen.get(ns) == "." for ns in NAMESPACES)


def test_a_moved_study_module_says_where_it_went():
    with pytest.raises(ImportError, match=r"armimp_jax\.study\.points moved to armimp_jax\.study\.schema\.points"):
        from armimp_jax.study import points  # noqa: F401
    with pytest.raises(ImportError, match=r"moved to armimp_jax\.study\.runs\.engine"):
        importlib.import_module("armimp_jax.study.engine")
    from armimp_jax.study import sweep

    with pytest.raises(AttributeError, match=r"a folder since 3\.3\.0.*armimp_jax\.study\.sweep\.sweep"):
        sweep.run_sweep  # noqa: B018
    assert importlib.import_module("armimp_jax.study.sweep.sweep").run_sweep is armimp_jax.study.run_sweep
