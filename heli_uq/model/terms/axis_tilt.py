"""``axis_tilt``: the yaw axis leans from the vertical, so gravity turns the body in yaw.

The paper's rig stands with its yaw axis vertical: gravity then does no work in yaw, and
the yaw has no preferred angle.  A base that is not level tilts the yaw axis by a small
angle ``beta`` towards an azimuth ``psi_b``.  The body's centre of mass lies
``d(theta) = r_c cos theta - h sin theta`` [m] from the yaw axis, along the arm (the
distance in ``M22``), and ``r_c sin theta + h cos theta`` above the pivot (the paper's
potential, Sec. 2.4).  To first order in ``beta`` the tilt raises it by
``beta d(theta) cos(psi - psi_b)``, so the potential energy gains::

    P_tilt = m g d(theta) (b_c cos psi + b_s sin psi)     [J]

with the tilt's components ``b_c = beta cos psi_b``, ``b_s = beta sin psi_b`` [rad] (in
Cartesian form the "no tilt" value 0 is inside the support and the posterior has one
mode, where ``(beta, psi_b)`` has a circle of them at 0).  The generalized forces
``Q = -dP_tilt/dx`` are::

    Q_psi   = m g d(theta) (b_c sin psi - b_s cos psi)
    Q_theta = m g (r_c sin theta + h cos theta) (b_c cos psi + b_s sin psi)

The yaw part is a restoring torque towards the azimuth where the arm hangs lowest (a
pendulum in yaw, like a spring but periodic and scaled by the arm's reach); the pitch part
is a gravity torque that varies with yaw.  Its rate near the yaw's rest angle is
``sqrt(m g d beta / M22)`` (:meth:`AxisTilt.stiffness`).  The term reads the mechanics'
``m, g, r_c, h``; ``b_c, b_s`` do not scale with the inertias (they are angles).  Tested
against the Euler-Lagrange equations of ``K - P - P_tilt`` by autodiff and by the energy
``K + P + P_tilt`` it conserves (``tests/test_axis_tilt.py``).  Outside the discovery
vocabulary (:data:`heli_uq.model.terms.EFFECTS`); on the pitch axis it is refused.
"""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from heli_uq.model.parameter import AXES, Parameter
from heli_uq.model.prior import Prior
from heli_uq.model.terms.base import AbstractEffect, AbstractTorque
from heli_uq.model.terms.rigid_body import GRAVITY_PARAMETERS, centre_of_mass, centre_of_mass_radius, weight

__all__ = ["AxisTilt", "TILT_PRIOR_SD"]

#: Prior sd [rad] of each tilt component: a base levelled by eye is within a few degrees.
TILT_PRIOR_SD = 0.05


class AxisTilt(AbstractEffect, AbstractTorque):
    """Gravity's torques on a yaw axis tilted by ``(b_c, b_s)`` (module docstring);
    ``axis`` must be ``"yaw"``."""

    kind: ClassVar[str] = "axis_tilt"
    summary: ClassVar[str] = (
        "yaw only: the yaw axis leans from the vertical by (b_c, b_s) towards psi = 0 and pi/2, so "
        "gravity turns the body in yaw (0 = level)")
    input_only: ClassVar[bool] = False
    axis: str = eqx.field(static=True, default="yaw")

    def __check_init__(self):
        if self.axis != "yaw":
            raise ValueError(f"axis_tilt tilts the yaw axis, found axis {self.axis!r}")

    def _declare(self):
        return tuple(Parameter(name, "rad", 0.0, Prior("normal", 0.0, TILT_PRIOR_SD), "real", False, None,
                               f"tilt of the yaw axis towards psi = {towards}", 0.0)
                     for name, towards in (("b_c", "0"), ("b_s", "pi/2")))  # fmt: skip

    def reads(self):
        return GRAVITY_PARAMETERS

    def acts_on(self) -> tuple[str, ...]:
        """Both axes: the tilted potential varies with pitch and with yaw."""
        return AXES

    def potential(self, p, x):
        """``P_tilt`` [J] at ``x = (theta, psi)`` (module docstring)."""
        reach, _ = centre_of_mass(p, x[0])
        return weight(p) * reach * self._lean(p, x[1])[0]

    def __call__(self, p, x, v, u):
        reach, height = centre_of_mass(p, x[0])
        rise, slope = self._lean(p, x[1])
        return weight(p) * height * rise, weight(p) * reach * slope

    def _lean(self, p, psi):
        """``(b_c cos psi + b_s sin psi, b_c sin psi - b_s cos psi)`` [rad]: the tilt's rise
        along the arm at yaw ``psi`` and minus its derivative in ``psi``."""
        b_c, b_s = p[self.name("b_c")], p[self.name("b_s")]
        c, s = jnp.cos(psi), jnp.sin(psi)
        return b_c * c + b_s * s, b_c * s - b_s * c

    def stiffness(self, p, inertia):
        f = {k: np.asarray(p[k], dtype=float) for k in (*self.reads(), self.name("b_c"), self.name("b_s"))}
        torque = weight(f) * centre_of_mass_radius(f) * np.hypot(f[self.name("b_c")], f[self.name("b_s")])
        return np.sqrt(torque / np.asarray(inertia[1], dtype=float))
