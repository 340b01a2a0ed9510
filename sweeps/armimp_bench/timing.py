"""What the benchmarks share (``armimp_bench``): timing in alternation (in this process or across child processes),
a digest of a simulation's outputs, and writing a table as Markdown and JSON. Importing it
imports no JAX (so ``--help`` stays fast): JAX is imported inside the functions that time it."""

from __future__ import annotations

import hashlib
import json
import pathlib
import subprocess
import sys
import time


def alternate(runs, repeats: int) -> list[list[float]]:
    """Seconds of each of ``runs`` (callables returning JAX values, ``block_until_ready``
    included), ``repeats`` times each, round robin: the shared host's slow drift hits every
    run alike (runs timed one after the other compare times taken minutes apart)."""
    import jax

    times = [[] for _ in runs]
    for _ in range(repeats):
        for run, t in zip(runs, times):
            t0 = time.perf_counter()
            jax.block_until_ready(run())
            t.append(time.perf_counter() - t0)
    return times


def digest(sim) -> str:
    """SHA-256 of a simulation's outputs (``x``, ``xd``, ``fh``, ``fu``, ``diverged``): equal
    digests, equal bits."""
    import numpy as np

    leaves = (sim.x, sim.xd, sim.fh, sim.fu, sim.diverged)
    return hashlib.sha256(b"".join(np.asarray(a).tobytes() for a in leaves)).hexdigest()


def run_children(specs: dict, repeats: int, cases: int, *, what: str) -> tuple[dict, dict]:
    """Time ``cases`` cases in child processes, alternating case by case and child by child.

    ``specs``: ``{name: (command, environment)}``. Each child prints one JSON line when it is
    ready, then for each stdin line ``CASE`` runs that case and prints its seconds. Returns
    ``(ready, times)``: per name the child's JSON line, and per ``(name, case)`` the seconds of
    its ``repeats`` runs. A child that dies before it is ready ends the script with one line."""
    children, ready = {}, {}
    for name, (cmd, env) in specs.items():
        child = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env)
        line = child.stdout.readline()
        if not line:
            sys.exit(f"{what}: the {name} child failed (exit {child.wait()})")
        children[name], ready[name] = child, json.loads(line)
    times = {(name, i): [] for name in children for i in range(cases)}
    for _ in range(repeats):
        for i in range(cases):
            for name, child in children.items():
                child.stdin.write(f"{i}\n")
                child.stdin.flush()
                times[(name, i)].append(float(child.stdout.readline()))
    for child in children.values():
        child.stdin.close()
        child.wait()
    return ready, times


def serve_cases(runs) -> None:
    """The child's side of ``run_children``: for each stdin line ``CASE``, run ``runs[CASE]``
    and print its seconds."""
    import jax

    for line in sys.stdin:
        run = runs[int(line)]
        t0 = time.perf_counter()
        jax.block_until_ready(run())
        print(time.perf_counter() - t0, flush=True)


def markdown_head(*columns: str) -> list[str]:
    """The header and rule lines of a Markdown table of ``columns``."""
    return ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]


def markdown_table(caption: str, columns, rows) -> str:
    """``caption``, a blank line and a Markdown table of ``columns`` with one line per row of
    ``rows`` (each an iterable of cells, written with ``str``)."""
    body = ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join([caption, "", *markdown_head(*columns), *body])


def save_table(out: pathlib.Path, stem: str, markdown: str, record) -> None:
    """``markdown`` (and a newline) to ``OUT/STEM.md`` and ``record`` as JSON (indent 1) to
    ``OUT/STEM.json``, creating ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{stem}.md").write_text(markdown + "\n")
    (out / f"{stem}.json").write_text(json.dumps(record, indent=1))
