"""``stiction``: breakaway friction above the sliding level (the Stribeck part), on one axis.

``T = -F_s exp(-(omega / omega_b)^2) tanh(omega / omega_s)`` [N m], with ``F_s`` >= 0
[N m] the static friction in excess of the sliding level, ``omega`` the axis' rate
[rad/s], ``omega_b`` [rad/s] the Stribeck velocity over which the excess fades once the
axis slides (default :data:`OMEGA_B`) and ``omega_s`` the smoothing width of the sign
(default :data:`~heli_uq.model.terms.coulomb_friction.OMEGA_S`, the same as
``coulomb_friction``'s).  Both widths are options of the term, not sampled parameters.

With ``coulomb_friction`` on the same axis the friction law is the Stribeck curve
``-(F_c + F_s exp(-(omega / omega_b)^2)) tanh(omega / omega_s)``: a stuck axis holds
until the applied torque exceeds ``F_c + F_s`` (the breakaway level), and once it slides
faster than ``omega_b`` the friction is ``F_c``.  So the axis breaks away later and then
moves further than under Coulomb friction alone: the stick-slip hysteresis of a real
bearing.  The effects table names the sliding level only; this term is the "stiction
variant (breakaway level above the sliding level)" the table welcomes, kept outside the
discovery vocabulary (:data:`heli_uq.model.terms.EFFECTS`) so that a record is still
named with the table's effects.  Alone (``F_c = 0``) it is a pure static friction.

Stiffness: near ``omega = 0`` the law's slope is ``F_s / omega_s``, so the term adds the
rate ``F_s / (omega_s M)`` [1/s], like Coulomb friction; on one axis the two add
(:meth:`heli_uq.model.HeliModel.stiffness` sums the rates of the terms on each axis).
"""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp

from heli_uq.model.parameter import Parameter
from heli_uq.model.prior import Prior
from heli_uq.model.terms.base import AbstractEffect, AbstractTorque, axis_index, on_axis
from heli_uq.model.terms.coulomb_friction import OMEGA_S, rate_at_rest

__all__ = ["Stiction", "OMEGA_B"]

#: Default Stribeck velocity [rad/s]: ten smoothing widths, well below the rig's swings
#: (yaw rates of 0.2-1 rad/s), so the excess acts on the stuck and creeping axis only.
OMEGA_B = 0.02


class Stiction(AbstractEffect, AbstractTorque):
    """``-F_s exp(-(omega / omega_b)^2) tanh(omega / omega_s)`` on ``axis`` (module docstring)."""

    kind: ClassVar[str] = "stiction"
    summary: ClassVar[str] = (
        "breakaway friction above the sliding level, fading over omega_b (option, 0.02 rad/s); with "
        "coulomb_friction the Stribeck law")
    input_only: ClassVar[bool] = False
    holds_still: ClassVar[bool] = True
    axis: str = eqx.field(static=True, default="yaw")
    omega_s: float = eqx.field(static=True, default=OMEGA_S)
    omega_b: float = eqx.field(static=True, default=OMEGA_B)

    def __check_init__(self):
        for name in ("omega_s", "omega_b"):
            if not getattr(self, name) > 0:
                raise ValueError(f"stiction: {name} must be > 0 rad/s, found {getattr(self, name)!r}")

    def _declare(self):
        return (Parameter("F_s", "N m", 0.0, Prior("halfnormal", 0.05), "nonnegative", True,
                          None, "static friction in excess of the sliding level", 0.005),)  # fmt: skip

    def __call__(self, p, x, v, u):
        omega = v[axis_index(self.axis)]
        fade = jnp.exp(-((omega / self.omega_b) ** 2))
        return on_axis(self.axis, -p[self.name("F_s")] * fade * jnp.tanh(omega / self.omega_s))

    def stiffness(self, p, inertia):
        return rate_at_rest(p[self.name("F_s")], self.omega_s, inertia, self.axis)

    def describe(self):
        return {"effect": self.kind, "axis": self.axis, "omega_s": self.omega_s, "omega_b": self.omega_b}
