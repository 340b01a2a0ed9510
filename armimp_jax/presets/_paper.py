"""The paper's settings as values of the general simulator: arms, friction levels, trials."""

from __future__ import annotations

import math

import numpy as np

from .._checks import check_choice
from .._model.arm import Arm, arm_endpoint
from .._model.controllers import IMBIC, PD
from .._model.friction import LuGre
from .._simulate import make_trial
from ._tables import ARM_LOCATIONS, FRICTION_LEVELS, PERTURBATION_PEAKS

LOCATIONS = tuple(ARM_LOCATIONS)
FRICTION_LEVEL_NUMBERS = tuple(FRICTION_LEVELS)
PERTURBATION_LEVELS = tuple(PERTURBATION_PEAKS)


def location_endpoint(location: int) -> np.ndarray:
    """World-frame endpoint [m] of arm location 1-4 (Table 2 angles, docs/model.md section 3), ``(2,)``."""
    check_choice("arm location", location, LOCATIONS)
    loc = ARM_LOCATIONS[location]
    return arm_endpoint(math.radians(loc.shoulder_deg), math.radians(loc.elbow_deg))


def arm(location: int) -> Arm:
    """The arm of location 1-4 (Table 2): impedance matrices and endpoint."""
    check_choice("arm location", location, LOCATIONS)
    loc = ARM_LOCATIONS[location]
    return Arm(loc.mass, loc.damping, loc.stiffness, location_endpoint(location))


def friction(level: int) -> LuGre:
    """LuGre parameters of friction level 0 (none: ``NO_FRICTION``), 1 or 2 (Table 1)."""
    check_choice("friction level", level, FRICTION_LEVEL_NUMBERS)
    p = FRICTION_LEVELS[level]
    return LuGre(p.tau_c, p.tau_s, sigma0=p.sigma0, sigma1=p.sigma1, sigma2=p.sigma2, v_s=p.v_s)


def perturbation_peak(level: int) -> np.ndarray:
    """Per-axis peak ``|F_Delta|`` [N] of perturbation level 1-3 (Table 3), shape ``(2,)``."""
    check_choice("perturbation level", level, PERTURBATION_LEVELS)
    return PERTURBATION_PEAKS[level].copy()


def trial(
    controller: str,
    friction_level: int,
    location: int,
    *,
    mhat=None,
    acquisition: str = "instant",
    accel_estimate: str = "velocity",
    sensors=None,
    robot=None,
):
    """A trial of the paper: ``"pd"`` or ``"imbic"`` (paper gains, ``Mhat = 0.25 I`` kg unless
    ``mhat`` is given), friction level 0-2, arm location 1-4, on MIT-MANUS.

    ``mhat`` may be a traced ``(2, 2)`` array (vmap or grad over it). PD ignores it.
    """
    check_choice("controller", controller, ("pd", "imbic"))
    if controller == "pd":
        ctrl = PD()
    else:
        ctrl = IMBIC(accel_estimate=accel_estimate) if mhat is None else IMBIC(mhat, accel_estimate=accel_estimate)
    return make_trial(
        ctrl,
        arm=arm(location),
        friction=friction(friction_level),
        sensors=sensors,
        robot=robot,
        acquisition=acquisition,
    )
