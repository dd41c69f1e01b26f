"""``torsional_spring``: a restoring torque, e.g. the twist of the cables in the yaw shaft.

``T = -k (angle - psi_0)`` [N m] with ``k`` >= 0 [N m/rad] and ``psi_0`` [rad] the angle
at which the spring is relaxed.  On the yaw axis ``angle = psi`` (cable twist); on the
pitch axis ``angle = theta`` (the parameter keeps the name ``psi_0`` of the effects
table).  Linear in the state: no smoothing, no stiffness for plausible ``k``.
"""

from __future__ import annotations

import math
from typing import ClassVar

import equinox as eqx
import numpy as np

from heli_uq.model.parameter import Parameter
from heli_uq.model.prior import Prior
from heli_uq.model.terms.base import AbstractEffect, AbstractTorque, axis_index, on_axis

__all__ = ["TorsionalSpring"]


class TorsionalSpring(AbstractEffect, AbstractTorque):
    """``-k (angle - psi_0)`` on ``axis``."""

    kind: ClassVar[str] = "torsional_spring"

    summary: ClassVar[str] = 'a restoring torque -k (q - q_0) on the axis (cable twist on yaw)'
    input_only: ClassVar[bool] = False
    axis: str = eqx.field(static=True, default="yaw")

    def _declare(self):
        return (
            Parameter("k", "N m/rad", 0.0, Prior("halfnormal", 0.05), "nonnegative", True, None,
                      "torsional spring stiffness", 0.002),
            Parameter("psi_0", "rad", 0.0, Prior("normal", 0.0, math.pi), "real", False, None,
                      "angle at which the spring is relaxed", 0.0),
        )  # fmt: skip

    def __call__(self, p, x, v, u):
        angle = x[axis_index(self.axis)]
        return on_axis(self.axis, -p[self.name("k")] * (angle - p[self.name("psi_0")]))

    def stiffness(self, p, inertia):
        k = np.maximum(np.asarray(p[self.name("k")], dtype=float), 0.0)
        return np.sqrt(k / np.asarray(inertia[axis_index(self.axis)], dtype=float))
