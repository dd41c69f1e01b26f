"""``input_delay``: a motor acts on its voltage a fixed time late (a dead time).

The paper's torques follow the voltages at once; ``motor_lag`` lets them follow with a
first-order lag, which responds at once, if partly.  A dead time ``d`` [s] >= 0 (drive
electronics, a data logger that stamps the voltage early, a rotor that needs time to
break away from rest) shifts the voltage of one motor instead:

    u'(t) = u(t - d)

on the motor of ``axis`` (``pitch`` is ``u_theta``, ``yaw`` is ``u_psi``), and ``u'``
replaces ``u`` before every gain it feeds, on both axes, as for a dead band or a lag.
Before the record the voltage is taken as held at its first value.

The voltages are held on each solver step of length ``h``, so the shifted voltage is
piecewise constant too, with its switches ``d`` after the steps' ends.  The solver holds
the step's *mean* of ``u'``: with ``d = (n + f) h`` (``n`` an integer, ``0 <= f < 1``),
``(1 - f) u_{k-n} + f u_{k-n-1}`` on step ``k``, which gives each step the exact impulse
of the delayed voltage and is differentiable in ``d``.  Its independent form, the delayed
switch times integrated by the adaptive reference solve, is
:func:`heli_uq.simulation.reference_solve`'s.

Outside the discovery vocabulary (:data:`heli_uq.model.terms.EFFECTS`), like
``motor_lag``: offered to ``discover`` only by ``--candidates`` or ``--base-effects``.
"""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp

from heli_uq.model.parameter import Parameter
from heli_uq.model.prior import Prior
from heli_uq.model.terms.base import AbstractEffect, AbstractInputMap, axis_index

__all__ = ["InputDelay"]


class InputDelay(AbstractEffect, AbstractInputMap):
    """Dead time ``u'(t) = u(t - d)`` of the motor voltage of ``axis`` (module docstring).
    Per sample the map is the identity; it acts on the whole voltage sequence through
    :meth:`filter_sequence`."""

    kind: ClassVar[str] = "input_delay"
    summary: ClassVar[str] = (
        "a motor acts on its voltage late: u'(t) = u(t - d) (0 = none); the axis names the motor, as "
        "for deadband")
    filters_sequence: ClassVar[bool] = True
    axis: str = eqx.field(static=True, default="yaw")

    def _declare(self):
        return (Parameter("d", "s", 0.0, Prior("halfnormal", 0.5), "nonnegative", False,
                          None, "dead time of the motor's voltage", 0.1),)  # fmt: skip

    def delay(self, p):
        """``(axis index, d [s])``: the dead time, for the reference solve."""
        return axis_index(self.axis), p[self.name("d")]

    def filter_sequence(self, p, u, h):
        """The step means of the delayed voltage, shape (N, 2) [V].

        ``u`` (N, 2) [V]: the voltage held on each step ``[t_k, t_k + h)``; ``h`` [s]: the
        step.  Step ``k`` holds ``(1 - f) u_{k-n} + f u_{k-n-1}`` with ``d / h = n + f``;
        indices before the record read ``u_0``.
        """
        i = axis_index(self.axis)
        shift = jnp.maximum(p[self.name("d")], 0.0) / h
        n = jnp.floor(shift)
        f = shift - n
        source = jnp.arange(u.shape[0]) - n.astype(jnp.int32)  # the step u_{k-n}
        col = u[:, i]
        now, before = col[jnp.clip(source, 0, None)], col[jnp.clip(source - 1, 0, None)]
        return u.at[:, i].set((1.0 - f) * now + f * before)

    def __call__(self, p, u):
        return u
