"""From recorded signals to an impedance: Welch spectra and coherences, accuracy metrics and
the parametric M, B, K fit. Pure JAX on arrays; knows nothing of how the data were made."""
