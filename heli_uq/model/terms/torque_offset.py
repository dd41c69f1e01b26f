"""``torque_offset``: a constant torque on one axis.

``T = T_0`` [N m], any sign: an unmodelled bias (cable tension, a motor zero offset, an
imbalance that the gravity term does not capture).
"""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx

from heli_uq.model.parameter import Parameter
from heli_uq.model.prior import Prior
from heli_uq.model.terms.base import AbstractEffect, AbstractTorque, on_axis

__all__ = ["TorqueOffset"]


class TorqueOffset(AbstractEffect, AbstractTorque):
    """Constant torque ``T_0`` on ``axis``."""

    kind: ClassVar[str] = "torque_offset"

    summary: ClassVar[str] = 'a constant torque T_0 on the axis'
    input_only: ClassVar[bool] = True
    axis: str = eqx.field(static=True, default="yaw")

    def _declare(self):
        return (Parameter("T_0", "N m", 0.0, Prior("normal", 0.0, 0.05), "real", True, None,
                          "constant torque", 0.0, constant_torque=True),)  # fmt: skip

    def __call__(self, p, x, v, u):
        return on_axis(self.axis, p[self.name("T_0")])
