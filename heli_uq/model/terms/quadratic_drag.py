"""``quadratic_drag``: aerodynamic (quadratic) friction on one axis.

``T = -c omega |omega|`` [N m] with ``c`` >= 0 [N m s^2/rad^2] and ``omega`` the axis'
rate [rad/s].  Continuously differentiable, so no smoothing is needed.
"""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp

from heli_uq.model.parameter import Parameter
from heli_uq.model.prior import Prior
from heli_uq.model.terms.base import AbstractEffect, AbstractTorque, axis_index, on_axis

__all__ = ["QuadraticDrag"]


class QuadraticDrag(AbstractEffect, AbstractTorque):
    """``-c omega |omega|`` on ``axis``."""

    kind: ClassVar[str] = "quadratic_drag"

    summary: ClassVar[str] = 'quadratic drag -c omega |omega| on the axis'
    input_only: ClassVar[bool] = False
    axis: str = eqx.field(static=True, default="yaw")

    def _declare(self):
        return (Parameter("c", "N m s^2/rad^2", 0.0, Prior("halfnormal", 0.05), "nonnegative",
                          True, None, "quadratic drag coefficient", 0.005),)  # fmt: skip

    def __call__(self, p, x, v, u):
        omega = v[axis_index(self.axis)]
        return on_axis(self.axis, -p[self.name("c")] * omega * jnp.abs(omega))
