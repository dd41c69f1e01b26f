"""Generalized forces ``F(x, v, u)`` acting on the coordinates (theta, psi).

A torque term is an :class:`equinox.Module` called as ``torque(params, x, v, u)``
returning the generalized force ``(T_theta, T_psi)`` in N m.  The mechanics never
look inside it, so neural networks or named physical effects (Coulomb friction,
dead zone, cable spring, ...) are added by composing terms with :class:`SumTorque`
(or ``+``) without touching the Lagrangian.
"""

from __future__ import annotations

import abc

import equinox as eqx
import jax.numpy as jnp

__all__ = ["AbstractTorque", "LinearTorque", "SumTorque"]


class AbstractTorque(eqx.Module):
    """Interface of a generalized-force term.

    Subclasses implement ``__call__(params, x, v, u) -> (2,)`` where ``params`` is a
    :class:`~heli_uq.params.HeliParams`, ``x = (theta, psi)`` [rad],
    ``v = (omega_theta, omega_psi)`` [rad/s], ``u = (u_theta, u_psi)`` [V]; the result is
    ``(T_theta, T_psi)`` [N m].  Extra trainable parameters live as fields of the term.
    """

    @abc.abstractmethod
    def __call__(self, params, x, v, u):
        raise NotImplementedError

    def __add__(self, other: AbstractTorque) -> SumTorque:
        return SumTorque((self, other))


class LinearTorque(AbstractTorque):
    """Paper Sec. 2.5: ``F = K u - D v`` with

    ``K = [[K_theta_theta, -K_theta_psi], [K_psi_theta, -K_psi_psi]]``,
    ``D = diag(D_theta, D_psi)``.
    """

    def __call__(self, params, x, v, u):
        t_theta = params.K_theta_theta * u[0] - params.K_theta_psi * u[1] - params.D_theta * v[0]
        t_psi = params.K_psi_theta * u[0] - params.K_psi_psi * u[1] - params.D_psi * v[1]
        return jnp.stack([t_theta, t_psi])


class SumTorque(AbstractTorque):
    """Sum of several torque terms, e.g. ``LinearTorque() + CoulombFriction(...)``."""

    terms: tuple[AbstractTorque, ...]

    def __call__(self, params, x, v, u):
        total = self.terms[0](params, x, v, u)
        for term in self.terms[1:]:
            total = total + term(params, x, v, u)
        return total
