"""The docs name the repository's files as code (`armimp_jax/_model/sensors.py`), not as links out
of the site: every such path in the README and the user's docs exists (the changelog keeps its
history's paths), so a moved or removed file is caught here, as a broken link is by the site's
strict build (`mkdocs build --strict`)."""

import pathlib
import re

ROOT = pathlib.Path(__file__).resolve().parent.parent
PATH = re.compile(r"`((?:armimp_jax|sweeps|tests|docs)/[A-Za-z0-9_./*<>-]+)")


def _exists(path: str) -> bool:
    """A file or folder, or ``module.name`` of a Python file (``tests/test_claims_movement.judge``)."""
    return (ROOT / path).exists() or (ROOT / (path.rsplit(".", 1)[0] + ".py")).exists()


def test_every_repository_path_the_docs_name_exists():
    pages = [p for p in sorted((ROOT / "docs").glob("*.md")) if p.name != "CHANGELOG.md"] + [ROOT / "README.md"]
    named = [(p.name, m.group(1).rstrip(".")) for p in pages for m in PATH.finditer(p.read_text())]
    assert len(named) > 100  # the docs do name files: the pattern reads them
    missing = sorted({(page, path) for page, path in named if not set("*<") & set(path) and not _exists(path)})
    assert not missing, missing
