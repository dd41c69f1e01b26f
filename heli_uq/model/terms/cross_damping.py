"""``cross_damping``: a torque on one axis proportional to the other axis' rate.

``T = -D_x omega_other`` [N m] with ``D_x`` [N m s/rad] of either sign and
``omega_other`` the rate of the other axis [rad/s]: the off-diagonal of the paper's damping
matrix ``D``, which Sec. 2.5 takes diagonal.  A body that pitches moves its rotors through
the air across their discs, which changes their drag torque about the yaw axis (and a
yawing body the pitch rotor's inflow); the cables that cross both joints couple them too.
A hybrid posterior's network on the rig record leaned on the pitch rate for its yaw torque
(studies/notes/hybrid.md), which is this term's form; fitted there it buys the training
window and is refused by the held-out one (studies/notes/discovery.md).  Linear in the
state, so no smoothing and no stiffness is added.
"""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx

from heli_uq.model.parameter import Parameter
from heli_uq.model.prior import Prior
from heli_uq.model.terms.base import AbstractEffect, AbstractTorque, axis_index, on_axis

__all__ = ["CrossDamping"]


class CrossDamping(AbstractEffect, AbstractTorque):
    """``-D_x omega_other`` on ``axis``, ``omega_other`` the other axis' rate."""

    kind: ClassVar[str] = "cross_damping"
    summary: ClassVar[str] = (
        "a torque of the other axis' rate: -D_x omega_other, D_x of either sign (0 = none)")
    input_only: ClassVar[bool] = False
    axis: str = eqx.field(static=True, default="yaw")

    def _declare(self):
        return (Parameter("D_x", "N m s/rad", 0.0, Prior("normal", 0.0, 0.1), "real", True, None,
                          "torque per rad/s of the other axis' rate", 0.0),)  # fmt: skip

    def __call__(self, p, x, v, u):
        other = 1 - axis_index(self.axis)
        return on_axis(self.axis, -p[self.name("D_x")] * v[other])
