"""Fitting model parameters through the simulator: the map from unconstrained numbers to
positive definite matrices, gradient tuning of controller gains, and (next) model-based
identification and experiment design. Pure JAX on values and arrays: no files."""
