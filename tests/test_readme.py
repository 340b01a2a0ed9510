"""The README's two commands are the ones CI and users run."""

import pathlib
import re

ROOT = pathlib.Path(__file__).resolve().parents[1]


def _commands():
    readme = (ROOT / "README.md").read_text()
    return re.findall(r"```bash\n(.*?)```", readme, flags=re.S)


def test_ci_runs_exactly_the_readme_test_command():
    ci = (ROOT / ".ci" / "run").read_text().strip().splitlines()[-1]
    assert any(ci in block for block in _commands()), ci


def test_readme_main_command_runs_the_reproduction():
    assert any("python sweeps/reproduce_paper.py" in block and "pip install" in block for block in _commands())
