"""The public names: one lazy table per face (``armimp_jax``, ``armimp_jax.study``), and
``__all__``, the table and the lists in docs/design.md ("The public names") agree; every
name loads from the module the table names."""

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
