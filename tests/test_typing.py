"""A user's type checker reads the public face: mypy resolves every public name (no ``Any``)
through the ``TYPE_CHECKING`` imports of ``armimp_jax/__init__.py`` and flags a moved or
misspelt one, and the README's quick start, the docs' example files and docs/extending.md's
classes pass it."""

import pathlib
import re
import subprocess
import sys

import armimp_jax

ROOT = pathlib.Path(__file__).resolve().parents[1]
NAMESPACES = [n for n in armimp_jax._NAMESPACES if n not in ("presets", "paper", "study")]


def _mypy(files, cache):
    cmd = [sys.executable, "-m", "mypy", "--cache-dir", str(cache), "--follow-imports=silent"]
    cmd += ["--ignore-missing-imports", "--no-error-summary", "--hide-error-context", *map(str, files)]
    return subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, timeout=600)


def test_mypy_resolves_every_public_name_and_passes_the_quick_start_and_examples(tmp_path):
    readme = re.findall(r"```python\n(.*?)```", (ROOT / "README.md").read_text(), flags=re.S)[0]
    guide = re.findall(r"```python\n(.*?)```", (ROOT / "docs" / "extending.md").read_text(), flags=re.S)[:2]
    names = [f"aj.{n}" for n in armimp_jax.__all__ if n != "runtime"]
    names += [f"aj.{ns}.{n}" for ns in NAMESPACES for n in __import__(f"armimp_jax.{ns}", fromlist=["_"]).__all__]
    reveal = "import armimp_jax as aj\n" + "".join(f"reveal_type({n})\n" for n in names)
    reveal += "reveal_type(aj.presets.arm)\nreveal_type(aj.study.run_sweep)\n"
    wrong = "import armimp_jax as aj\n\naj.assess\naj.simulte\n"  # a moved name and a typo: flagged
    files = {"quickstart.py": readme, "guide.py": "\n".join(guide), "reveal.py": reveal, "wrong.py": wrong}
    for name, text in files.items():
        (tmp_path / name).write_text(text)
    examples = sorted((ROOT / "docs" / "examples").glob("*.py"))
    run = _mypy([*(tmp_path / n for n in files), *examples], ROOT / ".mypy_cache")
    errors = [line for line in run.stdout.splitlines() if ": error:" in line]
    flagged = [line for line in errors if "wrong.py" in line]
    assert run.returncode == 1 and len(flagged) == 2, run.stdout + run.stderr
    assert all('has no attribute "' in line for line in flagged), flagged
    unexpected = [line for line in errors if "wrong.py" not in line]
    assert not unexpected, "\n".join(unexpected)
    revealed = re.findall(r"reveal\.py:(\d+): note: Revealed type is \"(.*)\"", run.stdout)
    names += ["aj.presets.arm", "aj.study.run_sweep"]
    assert len(revealed) == len(names)
    unresolved = [names[int(line) - 2] for line, kind in revealed if kind == "Any"]
    assert not unresolved, f"a type checker sees these as Any: {unresolved}"
