"""``quadratic_thrust``: a torque quadratic in the voltage of the axis' own motor.

Propeller thrust grows roughly with the square of the rotor speed, so the linear gain
``K u`` may need a quadratic part.  On the pitch axis the pitch motor adds
``+k_q u_theta |u_theta|`` (the sense of ``+K_theta_theta u_theta``); on the yaw axis
the yaw motor adds ``-k_q u_psi |u_psi|`` (the sense of ``-K_psi_psi u_psi``).  ``k_q``
[N m/V^2] may be negative (a thrust that grows less than linearly).  The voltage is the
one after any dead band.  Inputs are held on each sample interval: no stiffness.
"""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp

from heli_uq.model.parameter import Parameter
from heli_uq.model.prior import Prior
from heli_uq.model.terms.base import AbstractEffect, AbstractTorque, axis_index, on_axis

__all__ = ["QuadraticThrust"]


class QuadraticThrust(AbstractEffect, AbstractTorque):
    """``±k_q u |u|`` of ``axis``' own motor on ``axis`` (module docstring)."""

    kind: ClassVar[str] = "quadratic_thrust"
    summary: ClassVar[str] = (
        "an extra thrust k_q u |u| of the axis' own motor, in the sense of its linear gain")
    input_only: ClassVar[bool] = True
    axis: str = eqx.field(static=True, default="yaw")

    def _declare(self):
        return (Parameter("k_q", "N m/V^2", 0.0, Prior("normal", 0.0, 0.05), "real", True, None,
                          "quadratic motor torque coefficient", 0.0),)  # fmt: skip

    def __call__(self, p, x, v, u):
        i = axis_index(self.axis)
        sense = 1.0 if self.axis == "pitch" else -1.0
        return on_axis(self.axis, sense * p[self.name("k_q")] * u[i] * jnp.abs(u[i]))
