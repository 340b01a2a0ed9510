"""The result of ``fit_impedance``: M, B, K with standard errors, VAF, lack of fit and the
diagnostics that say when to distrust them; its intervals, warnings and a printed summary."""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from .._checks import check_choice
from .diagnose import FitDiagnostics, fit_warnings
from .parametric import ACQUISITIONS, DEFAULT_PERIOD, ELEMENTS, regressors

PARAMETERS = (("M", "mass", "kg"), ("B", "damping", "N s/m"), ("K", "stiffness", "N/m"))


class ImpedanceFit(NamedTuple):
    """``M, B, K`` fitted to an impedance, with standard errors, %VAF and lack of fit (a pytree).

    ``mass`` [kg], ``damping`` [N s/m], ``stiffness`` [N/m], each ``(2, 2)`` indexed
    ``[output, input]`` like ``Z``, and their standard errors ``mass_se``, ``damping_se``,
    ``stiffness_se`` (same units and shapes). ``vaf`` ``(2, 2)`` and ``vaf_overall`` (scalar):
    variance accounted for [%], ``100 (1 - sum |Z - Z_fit|^2 / sum |Z|^2)`` per element and
    over all elements, ``Z_fit`` the model of the recorded ``Z`` (its acquisition included).
    ``dof`` ``(2, 2)``: degrees of freedom of the standard errors (``se="residual"``: ``2 F_w
    - 3``, ``F_w`` bins with positive weight; ``se="spectral"``: the smallest of the
    element's three Satterthwaite values); a two-sided 95% interval is
    ``value +- t_0.975(dof) * se`` (``interval``).

    ``delay``, ``delay_se`` [s], ``delay_dof``: the fitted force-channel delay
    (``acquisition="delay"``; 0, 0 and NaN otherwise). ``lack_of_fit`` ``(2, 2)`` and
    ``lack_of_fit_overall``: the residuals' weighted sum of squares over its expected value
    when the model holds (about 1 then; larger when it does not), and ``lack_of_fit_p``,
    ``lack_of_fit_p_overall``: their p-values (an F test); NaN without ``Estimate.error``.
    ``diagnostics``: a ``FitDiagnostics`` of the estimate it was fitted to (NaN for a bare
    ``Z`` array), which ``warnings`` reads. Under ``jax.vmap`` every field gains the batch axis.
    """

    mass: jnp.ndarray
    damping: jnp.ndarray
    stiffness: jnp.ndarray
    mass_se: jnp.ndarray
    damping_se: jnp.ndarray
    stiffness_se: jnp.ndarray
    vaf: jnp.ndarray
    vaf_overall: jnp.ndarray
    dof: jnp.ndarray
    delay: jnp.ndarray
    delay_se: jnp.ndarray
    delay_dof: jnp.ndarray
    lack_of_fit: jnp.ndarray
    lack_of_fit_p: jnp.ndarray
    lack_of_fit_overall: jnp.ndarray
    lack_of_fit_p_overall: jnp.ndarray
    diagnostics: FitDiagnostics

    def impedance(self, f, *, acquisition: str = "plain", period: float = DEFAULT_PERIOD):
        """The fitted model at ``f`` [Hz] ``(F,)``: ``(F, 2, 2)`` [N/m]. ``acquisition="plain"``
        (default): the arm's ``M s^2 + B s + K`` at ``s = j 2 pi f``; another acquisition gives
        the model of the recorded ``Z`` (``fit_impedance``), with ``period`` ``L`` [s]."""
        check_choice("acquisition", acquisition, ACQUISITIONS)
        omega = 2.0 * jnp.pi * jnp.asarray(f, dtype=jnp.float64)
        x = regressors(omega, acquisition, period)  # (F, 3): K, M, B
        z = sum(x[:, k, None, None] * p[None] for k, p in enumerate((self.stiffness, self.mass, self.damping)))
        if acquisition == "delay":
            z = z * jnp.exp(-1j * omega * self.delay)[:, None, None]
        return z

    def interval(self, name: str, level: float = 0.95):
        """Two-sided ``level`` interval of ``name`` (``"mass"``, ``"damping"``, ``"stiffness"``
        or ``"delay"``) as ``(low, high)`` NumPy arrays: ``value -+ t_(1+level)/2(dof) * se``
        (host only: the quantile comes from SciPy)."""
        import scipy.stats

        check_choice("parameter", name, ("mass", "damping", "stiffness", "delay"))
        if not 0 < level < 1:
            raise ValueError(f"level must lie strictly between 0 and 1, got {level}")
        value, se = np.asarray(getattr(self, name)), np.asarray(getattr(self, f"{name}_se"))
        dof = np.asarray(self.delay_dof if name == "delay" else self.dof)
        half = scipy.stats.t.ppf(0.5 + level / 2, np.where(np.isfinite(dof), dof, np.inf)) * se
        return value - half, value + half

    @property
    def warnings(self) -> list[str]:
        """What makes this fit untrustworthy, in words (``fit_warnings(self)``; one concrete fit)."""
        return fit_warnings(self)

    def summary(self, level: float = 0.95) -> str:
        """The fit as text: every element of M, B, K with its ``level`` interval, the fitted
        delay, VAF and lack of fit, then every warning (one concrete fit)."""
        if np.ndim(np.asarray(self.mass)) != 2:
            raise ValueError("summary takes one fit (not a batch): index it first, jax.tree.map(lambda a: a[i], fits)")
        pct = f"{100 * level:g}%"
        lines = [f"{'':14s} {'value':>10s}   {pct} interval"]
        for sym, name, unit in PARAMETERS:
            low, high = self.interval(name, level)
            value = np.asarray(getattr(self, name))
            for i, j in ELEMENTS:
                label = f"{sym}{'xy'[i]}{'xy'[j]} [{unit}]"
                lines.append(f"{label:14s} {value[i, j]:10.4g}   [{low[i, j]:.4g}, {high[i, j]:.4g}]")
        if np.isfinite(np.asarray(self.delay_dof)):
            low, high = self.interval("delay", level)
            lines.append(f"{'delay [ms]':14s} {1e3 * float(self.delay):10.4g}   [{1e3 * low:.4g}, {1e3 * high:.4g}]")
        lines.append(f"VAF {float(self.vaf_overall):.1f}%")
        if np.isfinite(np.asarray(self.lack_of_fit_overall)):
            lines.append(
                f"lack of fit {float(self.lack_of_fit_overall):.3g} (about 1 when the model describes Z within its "
                f"errors; p = {float(self.lack_of_fit_p_overall):.2g})"
            )
        warnings = self.warnings
        lines += [f"WARNING: {w}" for w in warnings] or ["no warnings"]
        return "\n".join(lines)
