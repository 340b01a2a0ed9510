"""Fitting model parameters through the simulator, and bounding how well they can be fitted:
identification of the arm and the friction by indirect inference (``identify``: ``auxiliary``
statistics, the ``indirect`` binding function and covariance, over recordings and ensembles,
its self-check and results), the standard errors a planned experiment will give
(``predict_se``), the Cramér-Rao bound (``crlb``, along a reach too) and the record a precision
needs (``precision``), with a calibration carried in (``calibration_prior``). Experiment design
and the tuner are in ``_design``, the calibrations in ``_calibration``. Pure JAX on values and
arrays: no files."""
