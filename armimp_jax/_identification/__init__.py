"""Fitting model parameters through the simulator: the map from unconstrained numbers to
positive definite matrices, gradient tuning of controller gains, model-based identification
of the arm and the friction (``identify``) and the standard errors a planned experiment will
give (``predict_se``). Pure JAX on values and arrays: no files."""
