import jax

# Entry points switch float64 on; the library never does it on import.
jax.config.update("jax_enable_x64", True)
# Catch silent broadcasting between arrays of different rank.
jax.config.update("jax_numpy_rank_promotion", "raise")
