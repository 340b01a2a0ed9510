import json
import os
import pathlib

import jax
import numpy as np
import scipy.signal


def tree_equal(a, b) -> bool:
    """Bitwise equality of two pytrees of arrays (NaNs compare by bits)."""
    la, lb = jax.tree.leaves(a), jax.tree.leaves(b)
    return len(la) == len(lb) and all(
        np.asarray(x).shape == np.asarray(y).shape and np.asarray(x).tobytes() == np.asarray(y).tobytes()
        for x, y in zip(la, lb)
    )


def tree_allclose(a, b, *, rtol=1e-12, atol=0.0) -> bool:
    la, lb = jax.tree.leaves(a), jax.tree.leaves(b)
    return len(la) == len(lb) and all(np.allclose(x, y, rtol=rtol, atol=atol) for x, y in zip(la, lb))


def zoh_response(m, b, k, fd, period):
    """Exact ZOH response from rest of ``m xdd + b xd + k e = F_Delta`` (2-DOF), sampled at
    the period: an oracle independent of the simulator."""
    mi = np.linalg.inv(m)
    a = np.block([[np.zeros((2, 2)), np.eye(2)], [-mi @ k, -mi @ b]])
    bb = np.vstack([np.zeros((2, 2)), mi])
    ad, bd, *_ = scipy.signal.cont2discrete((a, bb, np.eye(4), np.zeros((4, 2))), period, "zoh")
    s, out = np.zeros(4), []
    for f in np.asarray(fd):
        out.append(s[:2].copy())
        s = ad @ s + bd @ f
    return np.array(out)


def env_without_jax(folder: pathlib.Path) -> dict:
    """The environment of a process in which ``import jax`` fails (a stand-in package first on
    ``PYTHONPATH``): a script that answers in it parsed its options before importing JAX. No
    clock is read, so a loaded host cannot fail it."""
    (folder / "jax").mkdir(exist_ok=True)
    (folder / "jax" / "__init__.py").write_text("raise ImportError('jax imported before the options were parsed')\n")
    return dict(
        os.environ, PYTHONPATH=os.pathsep.join([str(folder), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    )


def write_toml(path, config: dict) -> pathlib.Path:
    """TOML of ``config``, sections of plain values (JSON numbers, strings and arrays are TOML
    values too)."""
    lines = []
    for section, table in config.items():
        lines.append(f"[{section}]")
        lines += [f"{key} = {json.dumps(value)}" for key, value in table.items()]
    path.write_text("\n".join(lines) + "\n")
    return path
