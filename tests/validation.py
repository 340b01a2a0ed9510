"""The validation report: what the statistics tier (``pytest -m stats``) measured, written by the
run that measured it. Each figure the tier reports (``claims.report``) is saved as ``NAME.json`` in
the figures folder (``ARMIMP_STATS_OUT``, default ``results/stats``) with its run: the date, the
armimp_jax and JAX versions, the host and the test that asserted it. At the session's end the
report ``docs/validation.md`` is written from every figure in the folder, each with the outcome
of its test in the run that measured it: a partial run updates its figures and keeps the rest."""

from __future__ import annotations

import datetime
import json
import os
import pathlib
import platform
import subprocess

ROOT = pathlib.Path(__file__).resolve().parent.parent
REPORT = ROOT / "docs" / "validation.md"


def figures_folder() -> pathlib.Path:
    """Where the tier's figures go (``ARMIMP_STATS_OUT``, or ``results/stats``)."""
    return pathlib.Path(os.environ.get("ARMIMP_STATS_OUT") or ROOT / "results" / "stats")


def run_stamp() -> dict:
    """The measuring run: date (UTC), versions, host, and the test running now."""
    import jax

    import armimp_jax

    # the commit as well: an editable install's version is its metadata's, stale until reinstalled
    git = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True, text=True)
    return dict(
        date=datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC"),
        armimp_jax=armimp_jax.__version__,
        commit=git.stdout.strip() if git.returncode == 0 else None,
        jax=jax.__version__,
        host=f"{platform.machine()}, {os.cpu_count()} cores, {platform.processor() or platform.system()}",
        test=os.environ.get("PYTEST_CURRENT_TEST", "").rsplit(" ", 1)[0],
    )


def _flat(figures: dict, prefix: str = ""):
    """``(dotted name, value)`` of every leaf, nested figures (one per arm, per claim) included;
    the bands, the raw data and the run left out."""
    for key, value in figures.items():
        if not prefix and key in ("raw", "run", "outside", "bands"):
            continue
        if isinstance(value, dict):
            yield from _flat(value, f"{prefix}{key}.")
        else:
            yield f"{prefix}{key}", value


def _scalars(figures: dict) -> list[str]:
    """The figure's numbers, words and short lists of numbers, as ``name: value``."""
    out = []
    for key, value in _flat(figures):
        if isinstance(value, float):
            out.append(f"{key}: {value:.4g}")
        elif isinstance(value, (int, str)) and not isinstance(value, bool):
            out.append(f"{key}: {value}")
        elif isinstance(value, list) and 0 < len(value) <= 12 and all(isinstance(v, (int, float)) for v in value):
            out.append(f"{key}: " + ", ".join(f"{v:.4g}" for v in value))
    return out


def render(folder: pathlib.Path, outcomes: dict[str, str]) -> str:
    """The report's Markdown from every ``NAME.json`` in ``folder``; ``outcomes``: this session's
    ``{test node id: "passed" | "failed"}`` (a figure from an earlier run keeps its own outcome)."""
    lines = [
        "# Validation report",
        "",
        "Written by the statistics tier from its own output: `python -m pytest -m stats` (hours on 2 cores;",
        "a part, such as `tests/test_claims_calibration.py`, updates its own figures). Each",
        "figure gives the run that measured it and the outcome of the test that asserted it; the bands are",
        "the Monte Carlo's own (`tests/acceptance.py`). [performance.md](performance.md) keeps the runs",
        "behind the other figures the docs print, with their dates, versions and hosts.",
        "",
    ]
    names = sorted(p.stem for p in folder.glob("*.json"))
    if not names:
        return "\n".join(lines + ["No figure has been measured on this tree yet.", ""])
    lines += ["| figure | outcome | measured | armimp_jax | host |", "|---|---|---|---|---|"]
    saved = {n: json.loads((folder / f"{n}.json").read_text()) for n in names}
    for name in names:
        run = saved[name].setdefault("run", {})
        run["outcome"] = outcomes.get(run.get("test"), run.get("outcome", "not recorded"))
        version = run.get("armimp_jax", "?") + (f" ({run['commit']})" if run.get("commit") else "")
        cells = (run["outcome"], run.get("date", "?"), version, run.get("host", "?"))
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    for name in names:
        fig, run = saved[name], saved[name]["run"]
        lines += ["", f"## {name}", "", f"`{run.get('test', '?')}`: {run['outcome']}.", ""]
        lines += [f"- {s}" for s in _scalars(fig)]
        if "outside" in fig:
            lines.append(f"- outside its band: {fig['outside'] or 'none'}")
    return "\n".join(lines) + "\n"


def write(outcomes: dict[str, str], report: pathlib.Path = REPORT) -> pathlib.Path | None:
    """Record this session's outcomes in their figures, then write ``report`` from the figures
    folder (nothing when it holds no figure)."""
    folder = figures_folder()
    if not folder.is_dir() or not any(folder.glob("*.json")):
        return None
    for path in folder.glob("*.json"):
        figure = json.loads(path.read_text())
        test = figure.get("run", {}).get("test")
        if test in outcomes:
            figure["run"]["outcome"] = outcomes[test]
            _atomic(path, json.dumps(figure, indent=1) + "\n")
    _atomic(report, render(folder, outcomes))
    return report


def _atomic(path: pathlib.Path, text: str) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text)
    tmp.replace(path)


def read(report: pathlib.Path = REPORT) -> dict[str, dict]:
    """``{anchor: {"name", "outcome", "figures": {key: text}}}`` of a written report, keyed by each
    figure's anchor in the site and on GitHub; two figures with one anchor are refused."""
    out, current = {}, None
    for line in report.read_text().splitlines():
        if line.startswith("## "):
            name = line[3:].strip()
            key = anchor(name)
            if key in out:
                raise ValueError(f"{report}: figures {out[key]['name']!r} and {name!r} share an anchor")
            current = out[key] = dict(name=name, outcome=None, figures={})
        elif current is not None and line.startswith("`") and "`: " in line:
            current["outcome"] = line.rsplit("`: ", 1)[1].rstrip(".")
        elif current is not None and line.startswith("- ") and ": " in line:
            key, _, value = line[2:].partition(": ")
            current["figures"][key] = value
    return out


def anchor(name: str) -> str:
    """The heading's anchor as the site makes it: Python-Markdown's ``toc`` slug, mkdocs's default
    (and GitHub's, for the names the tier writes)."""
    from markdown.extensions.toc import slugify  # the site's own (the test extra installs mkdocs)

    return slugify(name, "-")
