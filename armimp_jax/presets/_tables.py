"""The paper's tables as data, with units: friction levels, arm locations, perturbation peaks.

Plain NumPy float64 (host constants); ``presets`` builds the general simulator's values
from them. Sources: docs/model.md sections 4, 10 and 3 (paper Tables 1-3); the
bristle and viscous parameters are ``LuGre``'s defaults, read from the class.
"""

from __future__ import annotations

import dataclasses
import types
from typing import NamedTuple

import numpy as np

from .._model.friction import LuGre


class FrictionLevel(NamedTuple):
    """LuGre parameters of one friction level (Table 1), the same on both joints."""

    tau_c: float  # Coulomb torque [N m]
    tau_s: float  # static (stiction) torque [N m]
    sigma0: float  # bristle stiffness [N m / rad]
    sigma1: float  # bristle damping [N m s / rad]
    sigma2: float  # viscous friction [N m s / rad]
    v_s: float  # Stribeck velocity [rad / s]


# The bristle, viscous and Stribeck parameters the paper adopts from Canudas de Wit et al.
# (docs/model.md section 15.1) are the defaults of ``LuGre``: stated there once, read here.
LUGRE_DEFAULTS = types.MappingProxyType(
    {f.name: f.default for f in dataclasses.fields(LuGre) if f.name in ("sigma0", "sigma1", "sigma2", "v_s")}
)

# Level 0 is no friction at all (``NO_FRICTION``); levels 1 and 2 use the defaults above.
FRICTION_LEVELS: dict[int, FrictionLevel] = {
    0: FrictionLevel(0.0, 0.0, 0.0, 0.0, 0.0, 1.0),
    1: FrictionLevel(1.0, 1.5, **LUGRE_DEFAULTS),
    2: FrictionLevel(4.0, 6.0, **LUGRE_DEFAULTS),
}


class ArmLocation(NamedTuple):
    """One arm posture of Table 2 (Dolan et al., subject A): joint angles and impedance."""

    shoulder_deg: float  # th_s [deg]
    elbow_deg: float  # th_e [deg], relative to the upper arm
    mass: np.ndarray  # M_h (2, 2) [kg]
    damping: np.ndarray  # B_h (2, 2) [N s / m]
    stiffness: np.ndarray  # K_h (2, 2) [N / m]


def _m(rows):
    return np.array(rows, dtype=np.float64)


ARM_LOCATIONS: dict[int, ArmLocation] = {
    1: ArmLocation(
        62.708,
        77.260,
        _m([[1.54, -0.57], [-0.65, 0.94]]),
        _m([[7.17, -6.14], [-6.19, 12.08]]),
        _m([[105.72, -104.11], [-127.35, 234.78]]),
    ),
    2: ArmLocation(
        41.870,
        62.578,
        _m([[0.79, -0.49], [-0.59, 1.56]]),
        _m([[3.24, 0.81], [1.18, 22.98]]),
        _m([[31.53, 41.36], [13.83, 380.55]]),
    ),
    3: ArmLocation(
        102.185,
        59.420,
        _m([[1.58, 0.00], [-0.10, 0.49]]),
        _m([[20.86, -10.69], [-12.32, 10.27]]),
        _m([[232.77, -145.13], [-147.64, 173.38]]),
    ),
    4: ArmLocation(
        37.301,
        126.831,
        _m([[2.24, -0.51], [-0.54, 0.71]]),
        _m([[13.17, -5.33], [-5.39, 6.93]]),
        _m([[146.30, -63.43], [-61.26, 98.45]]),
    ),
}

PERTURBATION_PEAKS: dict[int, np.ndarray] = {  # per-axis peak |F_Delta| [N] (Table 3)
    1: np.array([2.25, 2.25]),
    2: np.array([3.75, 3.75]),
    3: np.array([4.50, 4.50]),
}
