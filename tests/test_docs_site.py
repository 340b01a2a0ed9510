"""The documentation site (mkdocs.yml): the README's test command builds it with ``--strict``
(a broken link, anchor or docstring fails the build); here, what the build cannot see: every
page is in the site's navigation, the API reference lists every public name, and the getting
started page's example is the README's (which ``test_readme.py`` runs)."""

import pathlib
import re

import armimp_jax as aj

ROOT = pathlib.Path(__file__).resolve().parent.parent


def _nav_pages() -> set[str]:
    return set(re.findall(r":\s*([\w./-]+\.md)\s*$", (ROOT / "mkdocs.yml").read_text(), flags=re.M))


def test_every_page_is_in_the_navigation():
    pages = {p.name for p in (ROOT / "docs").glob("*.md")}
    assert pages == _nav_pages(), pages ^ _nav_pages()


def test_the_api_reference_lists_every_public_name():
    listed = set(re.findall(r"^::: armimp_jax\.(\w+)", (ROOT / "docs" / "api.md").read_text(), flags=re.M))
    assert set(aj.__all__) <= listed, sorted(set(aj.__all__) - listed)


def test_the_getting_started_example_is_the_readmes():
    def example(path):
        return re.findall(r"```python\n(.*?)```", (ROOT / path).read_text(), flags=re.S)[0]

    assert example("docs/index.md") == example("README.md")


def test_the_getting_started_commands_are_the_readmes():
    def commands(path):
        return re.findall(r"```bash\n(.*?)```", (ROOT / path).read_text(), flags=re.S)

    assert commands("docs/index.md") == commands("README.md")
