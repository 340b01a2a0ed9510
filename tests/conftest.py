import os
import pathlib

import jax

# Entry points switch float64 on; the library never does it on import.
jax.config.update("jax_enable_x64", True)
# Catch silent broadcasting between arrays of different rank.
jax.config.update("jax_numpy_rank_promotion", "raise")
# Compiled programs in a folder of the clone (gitignored), shared by the pytest workers and kept
# between runs: what one worker compiled the other loads. A caller's own ARMIMP_JAX_CACHE_DIR wins
# (``off`` for none); the scripts the tests run in-process read the same variable.
os.environ.setdefault("ARMIMP_JAX_CACHE_DIR", str(pathlib.Path(__file__).resolve().parents[1] / ".jax_cache"))

from armimp_jax import runtime  # noqa: E402  (after the cache folder is chosen)

runtime.use_compilation_cache(runtime.compilation_cache_dir())
