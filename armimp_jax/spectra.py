"""The classical route's pieces: Welch spectra, coherence, the fit's warnings, and accuracy
against a known arm.

A namespace of the public face: ``import armimp_jax as aj; aj.spectra.NAME`` (docs/design.md,
"The public names")."""

from __future__ import annotations

from ._estimation.diagnose import fit_warnings as fit_warnings
from ._estimation.estimate import input_coherence as input_coherence
from ._estimation.metrics import accuracy as accuracy
from ._estimation.welch import cross_spectral_matrix as cross_spectral_matrix
from ._estimation.welch import welch_segments as welch_segments

__all__ = ["accuracy", "cross_spectral_matrix", "fit_warnings", "input_coherence", "welch_segments"]
