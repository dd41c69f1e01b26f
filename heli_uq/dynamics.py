"""Equations of motion of the helicopter: closed form (Sec. 2.7), momentum/DAE form (Sec. 2.6).

Derivation (App. A).  With ``c = cos theta``, ``s = sin theta`` the Lagrangian is
``L = 1/2 M11 w_theta^2 + 1/2 M22(theta) w_psi^2 - m g (r_c s + h c)`` where
``M11 = J_bc + m r_c^2 + m h^2`` and ``M22 = J_bc c^2 + m (r_c c - h s)^2 + J_s``.
Differentiating,

``dM22/dtheta = -2 [J_bc c s + m (r_c c - h s)(r_c s + h c)]
             = -2 [(J_bc + m (r_c^2 - h^2)) c s + m r_c h (c^2 - s^2)] =: -2 a(theta)``

so ``dL/dtheta = -w_psi^2 a(theta) - m g (r_c c - h s)`` and
``(dp/dx v)_psi = -2 a(theta) w_theta w_psi``.  The equations of motion are

``M11 dw_theta/dt = -w_psi^2 a(theta) - m g (r_c c - h s) + T_theta``
``M22 dw_psi/dt   = 2 w_theta w_psi a(theta) + T_psi``.

**Printed-term error in the paper.**  Sec. 2.7 and App. A.2 print the ``h``-term of
``dL/dtheta`` as ``- r_c h (c^2 - s^2)``.  The derivation above (and App. A.2's own
``dp_psi/dtheta``) gives ``+ m r_c h (c^2 - s^2)``: the sign is flipped and the mass
``m`` is missing.  This package uses the derived term; ``tests/test_dynamics.py``
checks it against autodiff of the Lagrangian (:mod:`heli_uq.lagrangian`).  For
``h = 0`` both agree and reduce to Sec. 2.8.
"""

from __future__ import annotations

import abc

import equinox as eqx
import jax.numpy as jnp

from heli_uq.lagrangian import euler_lagrange_acceleration, helicopter_lagrangian
from heli_uq.torques import AbstractTorque, LinearTorque

__all__ = [
    "MechanicsCoefficients",
    "closed_form_mass_matrix",
    "closed_form_dl_dx",
    "closed_form_acceleration",
    "AbstractHeliModel",
    "HelicopterModel",
    "LagrangianModel",
    "momentum_vector_field",
    "total_energy",
]


def _a(params, c, s):
    """a(theta) = (J_bc + m (r_c^2 - h^2)) c s + m r_c h (c^2 - s^2)  [kg m^2]."""
    m, r, h = params.m, params.r_c, params.h
    return (params.J_bc + m * (r * r - h * h)) * c * s + m * r * h * (c * c - s * s)


def closed_form_mass_matrix(params, theta):
    """M(theta), shape (2, 2) [kg m^2] (Sec. 2.3)."""
    c, s = jnp.cos(theta), jnp.sin(theta)
    m11 = params.J_bc + params.m * params.r_c**2 + params.m * params.h**2
    m22 = params.J_bc * c**2 + params.m * (params.r_c * c - params.h * s) ** 2 + params.J_s
    zero = jnp.zeros_like(m11 * m22)
    return jnp.stack([jnp.stack([m11 + zero, zero]), jnp.stack([zero, m22 + zero])])


def closed_form_dl_dx(params, x, v):
    """dL/dx = (dL/dtheta, dL/dpsi), shape (2,) [N m], with the corrected h-term."""
    c, s = jnp.cos(x[0]), jnp.sin(x[0])
    dl_dtheta = -v[1] ** 2 * _a(params, c, s) - params.m * params.g * (params.r_c * c - params.h * s)
    return jnp.stack([dl_dtheta, jnp.zeros_like(dl_dtheta)])


def closed_form_acceleration(params, x, v, force):
    """Sec. 2.7 ODE solved for (dw_theta/dt, dw_psi/dt), shape (2,) [rad/s^2].

    Written term by term as in the paper (with the corrected ``+ m r_c h`` term); the
    simulator uses the algebraically equivalent :class:`MechanicsCoefficients`.
    """
    c, s = jnp.cos(x[0]), jnp.sin(x[0])
    a = _a(params, c, s)
    mm = closed_form_mass_matrix(params, x[0])
    dw_theta = (-v[1] ** 2 * a - params.m * params.g * (params.r_c * c - params.h * s) + force[0])
    dw_psi = 2.0 * v[0] * v[1] * a + force[1]
    return jnp.stack([dw_theta / mm[0, 0], dw_psi / mm[1, 1]])


class MechanicsCoefficients(eqx.Module):
    """Parameter combinations the mechanics depend on, precomputed once per parameter set.

    Using ``sin 2theta = 2 s c`` and ``cos 2theta = c^2 - s^2``:
    ``a = k_a sin2 + k_b cos2``, ``M22 = k_0 + k_a cos2 - k_b sin2``, with
    ``k_a = (J_bc + m r_c^2 - m h^2)/2``, ``k_b = m r_c h``,
    ``k_0 = J_s + (J_bc + m r_c^2 + m h^2)/2``; gravity ``m g r_c``, ``m g h``.
    This is the fast path of :func:`heli_uq.simulate.simulate` (one sin/cos per stage).
    """

    inv_m11: jnp.ndarray
    k_0: jnp.ndarray
    k_a: jnp.ndarray
    k_b: jnp.ndarray
    grav_c: jnp.ndarray
    grav_s: jnp.ndarray

    @classmethod
    def from_params(cls, params) -> MechanicsCoefficients:
        m, r, h, j = params.m, params.r_c, params.h, params.J_bc
        m11 = j + m * r * r + m * h * h
        return cls(
            inv_m11=1.0 / m11,
            k_0=params.J_s + 0.5 * m11,
            k_a=0.5 * (j + m * r * r - m * h * h),
            k_b=m * r * h,
            grav_c=m * params.g * r,
            grav_s=m * params.g * h,
        )

    def acceleration(self, theta, v, force):
        """(dw_theta/dt, dw_psi/dt), shape (2,), for pitch ``theta`` and rates ``v``."""
        s, c = jnp.sin(theta), jnp.cos(theta)
        s2, c2 = 2.0 * s * c, c * c - s * s
        a = self.k_a * s2 + self.k_b * c2
        m22 = self.k_0 + self.k_a * c2 - self.k_b * s2
        dw_theta = (-v[1] * v[1] * a - self.grav_c * c + self.grav_s * s + force[0]) * self.inv_m11
        dw_psi = (2.0 * v[0] * v[1] * a + force[1]) / m22
        return jnp.stack([dw_theta, dw_psi])


class AbstractHeliModel(eqx.Module):
    """A helicopter model: mechanics plus a generalized-force term.

    Subclasses implement :meth:`prepare` (parameter-only work, done once per solve)
    and :meth:`acceleration`.  :meth:`__call__` is the pure vector field
    ``f(t, y, args)`` with ``y = (theta, psi, omega_theta, omega_psi)`` and
    ``args = (params, u)``, ``u`` the (held) voltages, shape (2,) [V].
    """

    torque: eqx.AbstractVar[AbstractTorque]

    @abc.abstractmethod
    def prepare(self, params):
        """Parameter-only precomputation; returns a pytree passed to :meth:`acceleration`."""

    @abc.abstractmethod
    def acceleration(self, prepared, x, v, u):
        """Generalized accelerations (2,) [rad/s^2] at coordinates x, velocities v, input u."""

    def __call__(self, t, y, args):
        params, u = args
        a = self.acceleration(self.prepare(params), y[:2], y[2:], u)
        return jnp.concatenate([y[2:], a])


class HelicopterModel(AbstractHeliModel):
    """The paper's model with the closed-form (corrected) equations of motion: the fast path."""

    torque: AbstractTorque = LinearTorque()

    def prepare(self, params):
        return MechanicsCoefficients.from_params(params), params

    def acceleration(self, prepared, x, v, u):
        coeffs, params = prepared
        return coeffs.acceleration(x[0], v, self.torque(params, x, v, u))


class LagrangianModel(AbstractHeliModel):
    """Equations of motion derived by autodiff from any Lagrangian ``L(x, v, params)``.

    The default Lagrangian is the helicopter's; pass your own to study another
    mechanism without writing its equations of motion (paper challenge 3a).
    """

    torque: AbstractTorque = LinearTorque()
    lagrangian: object = eqx.field(static=True, default=helicopter_lagrangian)

    def prepare(self, params):
        return params

    def acceleration(self, prepared, x, v, u):
        force = self.torque(prepared, x, v, u)
        return euler_lagrange_acceleration(self.lagrangian, x, v, prepared, force)


def momentum_vector_field(t, z, args):
    """Momentum (DAE) form, Sec. 2.6: ``dx/dt = v``, ``dp/dt = dL/dx + F``, ``p = M(x) v``.

    The algebraic equation ``p = M(x) v`` is solved for ``v`` at every evaluation, so
    the state is ``z = (theta, psi, p_theta, p_psi)`` [rad, rad, kg m^2/s, kg m^2/s].

    Parameters
    ----------
    t : float
        Time [s] (unused: the system is autonomous for held inputs).
    z : array, shape (4,)
    args : tuple
        ``(params, u, torque)``: :class:`~heli_uq.params.HeliParams`, voltages (2,) [V]
        and an :class:`~heli_uq.torques.AbstractTorque`.
    """
    params, u, torque = args
    x, p = z[:2], z[2:]
    v = jnp.linalg.solve(closed_form_mass_matrix(params, x[0]), p)
    dp = closed_form_dl_dx(params, x, v) + torque(params, x, v, u)
    return jnp.concatenate([v, dp])


def total_energy(params, y):
    """K + P [J] for states ``y`` of shape (..., 4) (Sec. 2.3-2.4)."""
    from heli_uq.lagrangian import kinetic_energy, potential_energy

    y = jnp.asarray(y)
    x, v = jnp.moveaxis(y[..., :2], -1, 0), jnp.moveaxis(y[..., 2:], -1, 0)
    return kinetic_energy(params, x, v) + potential_energy(params, x)
