"""A lab's own controller in one file, with no package change: impedance in joint space.

    tau_k = K_q (q0 - q_k) - B_q qd_k,     F_u,k = F_Delta,k + J(q_k)^-T tau_k

Its ``step`` takes ``joints``, so the loop hands it the measured joint state (the encoders'
angles and rates, and the robot): no inverse kinematics of its own. The motors apply
``J^T F_u``, so the joint torque is ``tau_k`` plus the perturbation's. For small motions about
``q0`` it is the Cartesian PD with ``K = J^-T K_q J^-1`` and ``B = J^-T B_q J^-1`` (the suite
holds the two together). It holds a still arm (a step without ``path`` serves no reach).

    python sweeps/sweep.py --config my.toml --import docs/examples/joint_impedance.py --out DIR
"""

from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np

import armimp_jax as aj


class JointImpedance(aj.AbstractController):
    """A joint-space spring and damper about the equilibrium's joint angles."""

    kind: ClassVar[str] = "joint_impedance"
    UNITS: ClassVar[dict] = dict(k_q="N m/rad", b_q="N m s/rad")

    k_q: np.ndarray = eqx.field(converter=np.asarray, default=((40.0, 0.0), (0.0, 40.0)))
    b_q: np.ndarray = eqx.field(converter=np.asarray, default=((0.6, 0.0), (0.0, 0.6)))
    q0: jnp.ndarray | None = None  # the equilibrium's angles [rad], set by bind

    def bind(self, robot, q0, x0, *, period):
        return eqx.tree_at(lambda c: c.q0, self, jnp.asarray(q0), is_leaf=lambda v: v is None)

    def init(self, x0):
        return ()

    def step(self, memory, x, xd, fh, f_delta, x0, period, joints):
        tau = self.k_q @ (self.q0 - joints.q) - self.b_q @ joints.qd
        jac = aj.linear.jacobian(joints.q, joints.robot)
        return f_delta + jnp.linalg.solve(jac.T, tau), memory
