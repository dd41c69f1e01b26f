"""``deadband``: a motor dead zone on one motor's voltage.

``u' = sign(u) max(|u| - delta, 0)`` replaces that motor's voltage ``u`` [V] before every
gain it feeds (both axes: a dead band on the yaw motor reduces its yaw torque
``-K_psi_psi u_psi`` and its pitch torque ``-K_theta_psi u_psi`` alike).  ``delta`` [V]
>= 0; ``delta = 0`` is no dead band.  The axis names the motor: ``pitch`` is ``u_theta``,
``yaw`` is ``u_psi``.

No smoothing: the voltages are held constant on each sample interval, so the map is
applied to constants and introduces no stiffness in time; its kink at ``|u| = delta``
is in parameter space only.

That kink makes the fit's landscape piecewise: between two voltage levels of a record a
change of ``delta`` acts like a change of the gains and a constant torque, so a fit
started below every level stays there (a dead band of 0.6 V on the published profile,
whose yaw voltages start at 0.48 V, was fitted as an offset-like 0.1 V).  The term
therefore declares one start value in each interval between the record's voltage levels
(:meth:`DeadBand.start_grid`).
"""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from heli_uq.model.parameter import Parameter
from heli_uq.model.prior import Prior
from heli_uq.model.terms.base import AbstractEffect, AbstractInputMap, axis_index

__all__ = ["DeadBand"]

#: Voltage levels are told apart to 1e-5 V (the published record's resolution).
LEVEL_DECIMALS = 5


class DeadBand(AbstractEffect, AbstractInputMap):
    """Dead zone ``sign(u) max(|u| - delta, 0)`` on the motor of ``axis`` (module docstring)."""

    kind: ClassVar[str] = "deadband"
    summary: ClassVar[str] = (
        "a motor's dead zone: its voltage becomes sign(u) max(|u| - delta, 0) before every gain it "
        "feeds (the axis names the motor)")
    axis: str = eqx.field(static=True, default="yaw")

    def _declare(self):
        return (Parameter("delta", "V", 0.0, Prior("halfnormal", 0.5), "nonnegative", False,
                          None, "dead-band half-width of the motor voltage", 0.1),)  # fmt: skip

    def start_grid(self, u) -> dict:
        """Half the lowest nonzero voltage magnitude of this motor in ``u`` (N, 2) [V] and
        the midpoint between each two consecutive levels: one ``delta`` [V] per interval in
        which the dead band zeroes the same levels."""
        levels = np.unique(np.round(np.abs(np.asarray(u)[:, axis_index(self.axis)]), LEVEL_DECIMALS))
        levels = levels[levels > 0]
        if levels.size == 0:
            return {}
        return {self.name("delta"): np.concatenate([levels[:1] / 2, 0.5 * (levels[1:] + levels[:-1])])}

    def __call__(self, p, u):
        i = axis_index(self.axis)
        out = list(u)
        out[i] = jnp.sign(u[i]) * jnp.maximum(jnp.abs(u[i]) - p[self.name("delta")], 0.0)
        return tuple(out)
