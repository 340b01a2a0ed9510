import json
import os
import pathlib

import jax
import numpy as np
import pytest
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


def global_state() -> dict:
    """What a test must leave as it found it: the XLA flags (every later compilation of the
    worker, and every process it starts, reads them), the suite's JAX settings, the devices JAX
    sees, and the SIMD lanes that ``simulate_batch`` pads a batch to. Cheap: no JAX computation."""
    from armimp_jax import runtime

    return {
        "XLA_FLAGS": os.environ.get("XLA_FLAGS"),
        "jax_enable_x64": jax.config.jax_enable_x64,
        "jax_numpy_rank_promotion": jax.config.jax_numpy_rank_promotion,
        "device count": jax.device_count(),
        "runtime.vector_lanes()": runtime.vector_lanes(),
    }


def state_changes(before: dict, after: dict) -> list[str]:
    """One line per entry of ``global_state`` that differs: ``"name: before -> after"``, or for
    ``XLA_FLAGS`` the flags added and removed."""
    out = []
    for name in before:
        if after[name] == before[name]:
            continue
        if name == "XLA_FLAGS":
            was, now = (set((flags or "").split()) for flags in (before[name], after[name]))
            out.append(f"XLA_FLAGS added {sorted(now - was)}, removed {sorted(was - now)}")
        else:
            out.append(f"{name}: {before[name]!r} -> {after[name]!r}")
    return out


def restore_state(state: dict) -> None:
    """Put back what a process can put back (the device count cannot change once JAX started)."""
    if state["XLA_FLAGS"] is None:
        os.environ.pop("XLA_FLAGS", None)
    else:
        os.environ["XLA_FLAGS"] = state["XLA_FLAGS"]
    jax.config.update("jax_enable_x64", state["jax_enable_x64"])
    jax.config.update("jax_numpy_rank_promotion", state["jax_numpy_rank_promotion"])


@pytest.fixture(scope="session")
def suite_state() -> dict:
    """``global_state`` as the session's first test finds it: the suite's set-up."""
    return global_state()


def _fail_and_restore(what: str, changes: list[str], state: dict) -> None:
    restore_state(state)
    pytest.fail(f"{what}, so later tests on this worker would run differently: " + "; ".join(changes), pytrace=False)


@pytest.fixture(autouse=True)
def global_state_unchanged(suite_state):
    """Fails a test that leaves ``global_state`` changed (at its teardown), then puts it back, so
    the tests after it on the same worker run as they would alone. Its own fixtures
    (``monkeypatch``) have restored what they set by then: they are torn down before this autouse
    fixture. A change made between tests (a module's fixture) fails the next test's set-up."""
    before = global_state()
    changes = state_changes(suite_state, before)
    if changes:
        _fail_and_restore("the set-up changed between tests (a fixture of a wider scope)", changes, suite_state)
    yield
    changes = state_changes(before, global_state())
    if changes:
        _fail_and_restore("the test left the process's set-up changed", changes, before)
