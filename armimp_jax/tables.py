"""The paper's tables as data, with units: robot, friction, arm locations, perturbations, gains.

Everything here is plain NumPy float64 (host constants); the modules that build JAX
pytrees from these values validate the user's choice (level, location) and convert.
Sources: spec ``MODEL.md`` sections 2-4, 6-8 and 10 (paper Tables 1-4).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

# --- Timing (spec section 6) -------------------------------------------------
CONTROL_PERIOD = 1e-3  # L [s]; control and acquisition period
SAMPLE_RATE = 1000.0  # fs [Hz]
DEFAULT_SUBSTEPS = 100  # RK4 substeps per control period (h = 0.01 ms)
RECORD_SAMPLES = 50_000  # N, a 50 s record

# --- Human arm kinematics (spec section 2) -----------------------------------
UPPER_ARM_LENGTH = 0.21  # l_u [m]
FOREARM_LENGTH = 0.32  # l_f [m] (forearm plus hand)

# --- Robot: MIT-MANUS (spec section 3) ---------------------------------------
SHOULDER_LINK_LENGTH = 0.4064  # L_s [m]
ELBOW_LINK_LENGTH = 0.51435  # L_e [m]
INERTIA_C1 = 0.391162880843  # [kg m^2]
INERTIA_C2 = 0.226826719396  # [kg m^2]
INERTIA_C3 = 0.227888039765  # [kg m^2]
BASE_OFFSET_FROM_LOCATION_1 = np.array([0.0, 0.65])  # [m]; handle 0.65 m in front of the motors


class FrictionLevel(NamedTuple):
    """LuGre parameters of one friction level (Table 1), the same on both joints."""

    tau_c: float  # Coulomb torque [N m]
    tau_s: float  # static (stiction) torque [N m]
    sigma0: float  # bristle stiffness [N m / rad]
    sigma1: float  # bristle damping [N m s / rad]
    sigma2: float  # viscous friction [N m s / rad]
    v_s: float  # Stribeck velocity [rad / s]


# Level 0 is no friction at all. Its v_s = 1 is a placeholder that keeps v / v_s finite;
# with tau_c = tau_s = 0 and all sigmas 0 it has no effect on any value or gradient.
FRICTION_LEVELS: dict[int, FrictionLevel] = {
    0: FrictionLevel(0.0, 0.0, 0.0, 0.0, 0.0, 1.0),
    1: FrictionLevel(1.0, 1.5, 1e5, math.sqrt(1e5), 0.5, 1e-3),
    2: FrictionLevel(4.0, 6.0, 1e5, math.sqrt(1e5), 0.5, 1e-3),
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

# --- Perturbations (spec section 8, Table 3) ---------------------------------
PERTURBATION_CUTOFF = 15.0  # Butterworth cut-off f_max [Hz]
PERTURBATION_ORDER = 8
PERTURBATION_WARMUP = 2000  # samples of filter output discarded (2 s at 1 kHz)
PERTURBATION_PEAKS: dict[int, np.ndarray] = {  # per-axis peak |F_Delta| [N]
    1: np.array([2.25, 2.25]),
    2: np.array([3.75, 3.75]),
    3: np.array([4.50, 4.50]),
}
INPUT_COHERENCE_LIMIT = 0.4  # the paper's bound on the coherence between the two inputs

# --- Controller gains (spec section 7) ---------------------------------------
PD_STIFFNESS = 250.0 * np.eye(2)  # K_p [N / m]
PD_DAMPING = 4.0 * np.eye(2)  # K_v [N s / m]
DEFAULT_MHAT = 0.25 * np.eye(2)  # IMBIC gain [kg]

# --- Estimation (spec section 9, Table 4) ------------------------------------
WELCH_NPERSEG = 8192  # = nfft
WELCH_NOVERLAP = 6144
ESTIMATION_FMAX = 15.0  # [Hz]


def arm_endpoint(shoulder_rad, elbow_rad):
    """World-frame hand position [m] of the two-link arm (spec section 2), NumPy."""
    return np.array(
        [
            UPPER_ARM_LENGTH * np.cos(shoulder_rad) + FOREARM_LENGTH * np.cos(shoulder_rad + elbow_rad),
            UPPER_ARM_LENGTH * np.sin(shoulder_rad) + FOREARM_LENGTH * np.sin(shoulder_rad + elbow_rad),
        ]
    )


def location_endpoint(location: int) -> np.ndarray:
    """World-frame endpoint [m] of arm location ``location`` (1-4), shape ``(2,)``."""
    loc = ARM_LOCATIONS[location]
    return arm_endpoint(math.radians(loc.shoulder_deg), math.radians(loc.elbow_deg))


ROBOT_BASE = location_endpoint(1) + BASE_OFFSET_FROM_LOCATION_1  # p_b [m]
