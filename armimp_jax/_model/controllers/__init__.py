"""Controllers: the extension point (``base.AbstractController``, its registry) and its kinds,
one per module (``pd.PD``, ``imbic.IMBIC``, ``admittance.Admittance``)."""

from .admittance import Admittance as Admittance
from .base import CONTROLLER_KINDS as CONTROLLER_KINDS
from .base import AbstractController as AbstractController
from .base import Joints as Joints
from .base import controller_kind as controller_kind
from .base import matvec as matvec
from .base import reads_joints as reads_joints
from .base import step_takes as step_takes
from .imbic import DEFAULT_MHAT as DEFAULT_MHAT
from .imbic import IMBIC as IMBIC
from .pd import PD as PD
from .pd import PD_DAMPING as PD_DAMPING
from .pd import PD_STIFFNESS as PD_STIFFNESS
