import os
import pathlib

import jax

pytest_plugins = ("pytester",)  # tests/test_isolation.py runs a deliberate offender under the fixture below

# Entry points switch float64 on; the library never does it on import.
jax.config.update("jax_enable_x64", True)
# Catch silent broadcasting between arrays of different rank.
jax.config.update("jax_numpy_rank_promotion", "raise")
# Compiled programs in a folder of the clone (gitignored), shared by the pytest workers and kept
# between runs: what one worker compiled the other loads. A caller's own ARMIMP_JAX_CACHE_DIR wins
# (``off`` for none); the scripts the tests run in-process read the same variable.
os.environ.setdefault("ARMIMP_JAX_CACHE_DIR", str(pathlib.Path(__file__).resolve().parents[1] / ".jax_cache"))

from armimp_jax import runtime  # noqa: E402  (after the cache folder is chosen)

# The suite's set-up, explicit (importing armimp_jax sets none): one device per core (the
# sharded tests), XLA:CPU's small-loop kernel without LLVM unrolling, XLA's own vector width
# (256 bits) written out: flags already in XLA_FLAGS win, so a script's main() that a test runs
# in-process finds every option its configure() sets already set (on an AVX-512 host it would
# add 512-bit vectors, and vector_lanes() would go from 4 to 8 for the rest of the worker).
runtime.configure(vector_width=256, compilation_cache=False)
runtime.use_compilation_cache(runtime.compilation_cache_dir())

# Every test leaves that set-up as it found it: an autouse fixture fails one that does not
# (tests/helpers.py); so no test runs differently by which tests its worker ran before it.
from helpers import global_state_unchanged, suite_state  # noqa: E402, F401

# The suite runs file by file on two workers (``--dist loadfile``: a module's fixtures and
# compiled programs are made once). Its heaviest files go first, so the last file a worker
# takes is a short one, by worker seconds on a cold cache (docs/performance.md, "The test suite").
HEAVY_FIRST = (
    # the statistics tier (pytest -m stats), longest first
    "test_claims_matrix.py",
    "test_claims_identify.py",
    "test_claims_design.py",
    "test_claims_calibration.py",
    "test_claims_friction.py",
    "test_claims_fit.py",
    "test_claims_readme.py",
    "test_claims_numerics.py",
    # the default suite
    "test_identify.py",
    "test_bound.py",
    "test_reproduce.py",
    "test_fit.py",
    "test_recording.py",
    "test_bound_design.py",
    "test_graded.py",
    "test_estimate.py",
    "test_identify_recording.py",
    "test_tune.py",
    "test_readme.py",
    "test_simulate.py",
)


def pytest_collection_modifyitems(items):
    rank = {name: i for i, name in enumerate(HEAVY_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(HEAVY_FIRST)))  # stable: file order kept otherwise


# The statistics tier's report (tests/validation.py): the outcome of every stats test this session
# ran, and docs/validation.md written from the figures at the session's end (by the controller
# alone under xdist; not at all when no stats test ran).
_STATS_OUTCOMES: dict[str, str] = {}


def pytest_runtest_logreport(report):
    if "stats" in report.keywords and (report.when == "call" or report.outcome != "passed"):
        _STATS_OUTCOMES[report.nodeid] = report.outcome


def pytest_sessionfinish(session, exitstatus):
    if _STATS_OUTCOMES and not hasattr(session.config, "workerinput"):
        import validation

        validation.write(_STATS_OUTCOMES)
