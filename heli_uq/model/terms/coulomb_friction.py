"""``coulomb_friction``: dry friction on one axis, smoothed.

``T = -F_c tanh(omega / omega_s)`` [N m] with ``F_c`` >= 0 [N m] the sliding friction
level and ``omega`` the axis' rate [rad/s].  ``omega_s`` [rad/s] is the smoothing width
(default :data:`OMEGA_S`), an option of the term, not a sampled parameter.

Why this width.  Where the applied torque ``|T_a| < F_c`` the axis sticks: the smoothed
law holds it at the creep rate ``omega_s artanh(T_a / F_c)``, so the width bounds how
much a stuck axis drifts (about ``omega_s`` rad/s).  On a synthetic record with
``F_c = 0.004`` N m hidden in yaw, ``tanh(omega / 0.02)`` fitted no better than no
friction (the creep is the drift the effect should remove), ``tanh(omega / 0.002)``
reached the noise.  A sharp width makes the term stiff: its rate is
``F_c / (omega_s M)`` [1/s] near ``omega = 0`` (``M`` the axis inertia), 500/s for
``F_c / M = 1`` rad/s^2 and ``omega_s = 0.002``.  The simulator treats it with substeps
(:meth:`stiffness` sets their number, :func:`heli_uq.simulation.default_substeps`): fixed
RK4 substeps keep the exact zero-order hold of the inputs and the discrete adjoint,
and RK4 keeps the quasi-static creep rate exact in a stuck phase (a fixed point of the
ODE is a fixed point of every RK stage), so only the short settling transient needs the
resolution.  The choice is checked against an adaptive stiff reference solve
(:func:`heli_uq.simulation.reference_solve`, diffrax Kvaerno5).
"""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from heli_uq.model.parameter import Parameter
from heli_uq.model.prior import Prior
from heli_uq.model.terms.base import AbstractEffect, AbstractTorque, axis_index, on_axis

__all__ = ["CoulombFriction", "OMEGA_S", "rate_at_rest"]

#: Default smoothing width [rad/s] of the friction law (module docstring).
OMEGA_S = 0.002


def rate_at_rest(level, omega_s: float, inertia, axis: str):
    """Rate [1/s] a friction law ``level tanh(omega / omega_s)`` [N m] adds at rest on
    ``axis``: its slope ``level / omega_s`` over that axis' inertia (``inertia`` =
    ``(M11, M22_min)`` [kg m^2]); ``level`` and the inertias scalars or arrays of one
    shape (draws)."""
    return np.asarray(level, dtype=float) / (omega_s * np.asarray(inertia[axis_index(axis)], dtype=float))


class CoulombFriction(AbstractEffect, AbstractTorque):
    """``-F_c tanh(omega / omega_s)`` on ``axis`` (module docstring)."""

    kind: ClassVar[str] = "coulomb_friction"
    summary: ClassVar[str] = (
        "Coulomb friction -F_c tanh(omega / omega_s) on the axis (option omega_s, 0.002 rad/s)")
    input_only: ClassVar[bool] = False
    holds_still: ClassVar[bool] = True
    axis: str = eqx.field(static=True, default="yaw")
    omega_s: float = eqx.field(static=True, default=OMEGA_S)

    def __check_init__(self):
        if not self.omega_s > 0:
            raise ValueError(f"coulomb_friction: omega_s must be > 0 rad/s, found {self.omega_s!r}")

    def _declare(self):
        return (Parameter("F_c", "N m", 0.0, Prior("halfnormal", 0.05), "nonnegative", True,
                          None, "Coulomb (sliding) friction torque", 0.005),)  # fmt: skip

    def __call__(self, p, x, v, u):
        omega = v[axis_index(self.axis)]
        return on_axis(self.axis, -p[self.name("F_c")] * jnp.tanh(omega / self.omega_s))

    def stiffness(self, p, inertia):
        return rate_at_rest(p[self.name("F_c")], self.omega_s, inertia, self.axis)

    def describe(self):
        return {"effect": self.kind, "axis": self.axis, "omega_s": self.omega_s}
