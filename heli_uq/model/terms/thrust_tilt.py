"""``thrust_tilt``: the motors' yaw torques tilt with the pitch angle.

The paper's yaw torque (Sec. 2.5) is ``K_psi_theta u_theta - K_psi_psi u_psi``, the same
at every pitch angle.  Derived from the rig's geometry (the generalized force
``Q_psi = F . dr/dpsi`` of each motor), both yaw torques carry a factor ``cos theta``:

* the yaw rotor's thrust ``F`` points along the pitch axis, horizontal and normal to the
  arm, at the arm's point ``r (cos theta cos psi, cos theta sin psi, sin theta)``; so
  ``dr/dpsi = r cos theta (-sin psi, cos psi, 0)`` and ``Q_psi = F r cos theta``
  (``Q_theta = 0``);
* the pitch rotor's reaction torque acts along its shaft, the body normal
  ``(-sin theta cos psi, -sin theta sin psi, cos theta)``; its part along the vertical
  yaw axis is ``cos theta`` of it (its thrust has no moment about that axis).

(The thrust's point is ``r cos theta - h sin theta`` from the yaw axis when the rotor sits
``h`` off the arm's line; the rig's ``h`` is millimetres, so ``cos theta`` is kept.)  On
the rig the pitch angle spans -0.68 to -0.08 rad, where ``cos theta`` varies by 22 %: the
paper's constant gains are the gains at one average pitch.

The term blends the two laws with the tilt ``a`` (dimensionless, 0 = the paper's model,
1 = the derived one)::

    T_psi = (K_psi_theta u_theta - K_psi_psi u_psi) (1 - a (1 - cos theta))

and adds ``-a (1 - cos theta) (K_psi_theta u_theta - K_psi_psi u_psi)`` [N m] to the
linear torque's.  It reads the yaw gains through
:func:`~heli_uq.model.terms.linear_torque.motor_torques`, so a model needs the linear
torque.  Only the yaw axis has such a factor in this geometry; on pitch the term is
refused.  The term is outside the discovery vocabulary
(:data:`heli_uq.model.terms.EFFECTS`), like ``stiction``.
"""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp

from heli_uq.model.parameter import Parameter
from heli_uq.model.prior import Prior
from heli_uq.model.terms.base import AbstractEffect, AbstractTorque, on_axis
from heli_uq.model.terms.linear_torque import LINEAR_TORQUE_PARAMETERS, motor_torques

__all__ = ["ThrustTilt", "TILT_MAX"]

#: Upper bound of the tilt ``a``: twice the derived value, so that the data, not the
#: support, decide whether the rig's yaw torques fall off with pitch as ``cos theta``.
TILT_MAX = 2.0


class ThrustTilt(AbstractEffect, AbstractTorque):
    """The yaw torques' pitch dependence ``-a (1 - cos theta) (K_psi_theta u_theta -
    K_psi_psi u_psi)`` (module docstring); ``axis`` must be ``"yaw"``."""

    kind: ClassVar[str] = "thrust_tilt"
    summary: ClassVar[str] = (
        "yaw only: the yaw torques K_psi_theta u_theta - K_psi_psi u_psi times (1 - a (1 - cos "
        "theta)); a in [0, 2], 1 = the geometry's cos theta")
    input_only: ClassVar[bool] = False
    axis: str = eqx.field(static=True, default="yaw")

    def __check_init__(self):
        if self.axis != "yaw":
            raise ValueError(f"thrust_tilt acts on the yaw torques only, found axis {self.axis!r}")

    def _declare(self):
        support = ("bounded", 0.0, TILT_MAX)
        return (Parameter("a", "1", 0.0, Prior("uniform", 0.0, TILT_MAX), support, False, None,
                          "tilt of the yaw torques with pitch (1: cos theta)", 1.0),)  # fmt: skip

    def reads(self):
        return tuple(par.name for par in LINEAR_TORQUE_PARAMETERS if par.axis == "yaw" and par.input)

    def __call__(self, p, x, v, u):
        yaw_motors = motor_torques(p, u)[1]
        return on_axis(self.axis, -p[self.name("a")] * (1.0 - jnp.cos(x[0])) * yaw_motors)
