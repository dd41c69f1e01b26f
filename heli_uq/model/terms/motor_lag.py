"""``motor_lag``: a motor's thrust follows its voltage with a first-order lag.

The paper's torques follow the voltages at once.  A propeller motor takes time to spin up
and down (its rotor's inertia against its drive and drag), so the voltage that acts is

    tau du'/dt = u - u'

with time constant ``tau`` [s] >= 0 (``tau = 0``: no lag) on the motor of ``axis``
(``pitch`` is ``u_theta``, ``yaw`` is ``u_psi``), and ``u'`` replaces ``u`` before every
gain it feeds, on both axes, as for a dead band.  Before the record the voltage is taken as
held at its first value (``u'(0) = u(0)``).

The voltages are held on each solver step of length ``h``, so the lag is solved exactly
there: ``u'`` decays towards the held ``u`` as ``exp(-s / tau)``, and the solver holds
the step's *mean* of ``u'`` (:meth:`MotorLag.filter_sequence`), which gives each step the
exact impulse of the lagged voltage.  The lag adds no state to the ODE and no stiffness;
its independent form, the lag as two more states of a continuous ODE, is the adaptive
reference solve's (:func:`heli_uq.simulation.reference_solve`).

Outside the discovery vocabulary (:data:`heli_uq.model.terms.EFFECTS`), like
``thrust_tilt``: offered to ``discover`` only by ``--candidates`` or ``--base-effects``.
"""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp

from heli_uq.model.parameter import Parameter
from heli_uq.model.prior import Prior
from heli_uq.model.terms.base import AbstractEffect, AbstractInputMap, axis_index

__all__ = ["MotorLag", "TAU_FLOOR"]

#: Time constants [s] below this are treated as no lag (the step's mean is then the held
#: voltage to float64 precision for any step of 1e-4 s or more).
TAU_FLOOR = 1e-6


class MotorLag(AbstractEffect, AbstractInputMap):
    """First-order lag ``tau du'/dt = u - u'`` of the motor voltage of ``axis`` (module
    docstring).  Per sample the map is the identity; it acts on the whole voltage sequence
    through :meth:`filter_sequence`."""

    kind: ClassVar[str] = "motor_lag"
    summary: ClassVar[str] = (
        "a motor's thrust lags its voltage: tau du'/dt = u - u' (0 = none); the axis names the motor,"
        " as for deadband")
    filters_sequence: ClassVar[bool] = True
    axis: str = eqx.field(static=True, default="yaw")

    def _declare(self):
        return (Parameter("tau", "s", 0.0, Prior("halfnormal", 0.5), "nonnegative", False,
                          None, "time constant of the motor's first-order lag", 0.1),)  # fmt: skip

    def time_constant(self, p):
        """``(axis index, tau [s])``: the lag in continuous form, for the reference solve."""
        return axis_index(self.axis), p[self.name("tau")]

    def filter_sequence(self, p, u, h):
        """The step means of the lagged voltage, shape (N, 2) [V].

        ``u`` (N, 2) [V]: the voltage held on each step ``[t_k, t_k + h)``; ``h`` [s]: the
        step.  On step ``k`` the lagged voltage starts at ``f_k`` and decays towards ``u_k``:
        its mean is ``u_k + (f_k - u_k) w`` with ``w = (tau / h)(1 - exp(-h / tau))``, and
        ``f_{k+1} = u_k + (f_k - u_k) exp(-h / tau)``; ``f_0 = u_0``.
        """
        i = axis_index(self.axis)
        tau = p[self.name("tau")]
        lagged = tau > TAU_FLOOR
        safe = jnp.where(lagged, tau, 1.0)
        decay = jnp.where(lagged, jnp.exp(-h / safe), 0.0)
        weight = jnp.where(lagged, safe / h * -jnp.expm1(-h / safe), 0.0)
        col = u[:, i]

        def step(f, uk):
            return uk + (f - uk) * decay, uk + (f - uk) * weight

        _, means = jax.lax.scan(step, col[0], col)
        return u.at[:, i].set(means)

    def __call__(self, p, u):
        return u
