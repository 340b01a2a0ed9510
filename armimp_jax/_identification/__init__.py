"""Fitting model parameters through the simulator: the map from unconstrained numbers to
positive definite matrices, gradient tuning of controller gains, identification of the arm
and the friction by indirect inference (``identify``: ``auxiliary`` statistics, the
``indirect`` binding function and covariance), the standard errors a planned experiment
will give (``predict_se``) and experiment design (``design``, ``record_for``). Pure JAX on
values and arrays: no files."""
