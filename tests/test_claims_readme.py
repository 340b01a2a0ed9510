"""Statistics tier (``pytest -m stats``): the README's verdicts on the paper's claims (a)-(f),
"judged on 3 seeds by ``python sweeps/reproduce_paper.py``", asserted on that command's own run:
each row's verdict and measured values are the run's, every rule the README lists as failing
fails there with the value it prints, and "each verdict held on all 3 seeds"."""

import json
import pathlib
import re
import subprocess
import sys

import pytest
from claims import report

pytestmark = pytest.mark.stats

ROOT = pathlib.Path(__file__).resolve().parents[1]


def readme_rows():
    """``{key: (ours, verdict, failing)}`` of the README's table of the paper's claims."""
    text = (ROOT / "README.md").read_text()
    rows = re.findall(r"^\| \(([a-f])\) \| [^|]+ \| ([^|]+) \| \*\*(\w+)\*\* \| ([^|]+) \|$", text, flags=re.M)
    return {key: (ours.strip(), verdict, failing.strip()) for key, ours, verdict, failing in rows}


def test_the_readme_verdicts_are_the_reproductions_on_every_seed(tmp_path):
    rows = readme_rows()
    assert sorted(rows) == list("abcdef"), rows
    out = tmp_path / "paper"
    proc = subprocess.run(
        [sys.executable, "sweeps/reproduce_paper.py", "--out", str(out)], capture_output=True, text=True, cwd=ROOT
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    claims = {c["key"]: c for c in json.loads((out / "results.json").read_text())["claims"]}
    figures = {}
    for key, (ours, verdict, failing) in rows.items():
        c = claims[key]
        fails = [p for p in c["parts"] if not p["holds"]]
        figures[key] = dict(verdict=c["verdict"], seeds=c["seed_verdicts"], ours=c["ours"], failing=len(fails))
        assert c["verdict"] == verdict, (key, c["verdict"], verdict)
        assert c["ours"] == ours, (key, c["ours"], ours)
        assert c["seed_verdicts"] == {verdict: 3}, (key, c["seed_verdicts"])  # held on all 3 seeds
        listed = [] if failing == "none" else re.split(r"; (?![^()]*\))", failing)  # not inside parentheses
        assert len(listed) == len(fails), (key, listed, [p["label"] for p in fails])
        for p, cell in zip(fails, listed, strict=True):
            assert f"{p['value']:.3g}" in cell and f"({p['op']} " in cell, (key, p, cell)
    report("readme-verdicts", figures)
