"""The model's clock (docs/model.md section 7): the control and acquisition period ``L`` and
its sample rate. Every floor that needs the default period (simulation, perturbations, the
estimator's ``fs``, the fit's sampled-data models) takes it from here."""

CONTROL_PERIOD = 1e-3  # L [s], control and acquisition period: one sample of every signal per period
SAMPLE_RATE = 1000.0  # [Hz], 1 / CONTROL_PERIOD
