"""Lagrangian mechanics by automatic differentiation (paper Sec. 2.3-2.7, challenge 3a).

For any Lagrangian ``L(x, v, params)`` (a scalar, J) with generalized coordinates
``x`` and velocities ``v`` this module derives, with :mod:`jax` autodiff,

* the mass matrix ``M(x) = d^2 L / dv^2`` (kg m^2),
* the momenta ``p = dL/dv`` and the forces ``dL/dx``,
* the Euler-Lagrange acceleration from ``M dv/dt = dL/dx - (dp/dx) v + F``.

The helicopter's own kinetic and potential energy are given here too (App. A.1),
written from the geometry only: no equation of motion is typed by hand in this
module, which makes it the independent reference for the closed form in
:mod:`heli_uq.model.terms.rigid_body`.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp

__all__ = [
    "kinetic_energy",
    "potential_energy",
    "helicopter_lagrangian",
    "mass_matrix",
    "momenta",
    "euler_lagrange_acceleration",
]


def kinetic_energy(params, x, v):
    """K(x, v) [J] of body + shaft, paper App. A.1.

    ``K = 1/2 w_theta^2 (J_bc + m r_c^2 + m h^2)
    + 1/2 w_psi^2 (J_bc cos^2 theta + m (r_c cos theta - h sin theta)^2 + J_s)``.
    """
    theta = x[0]
    w_t, w_p = v[0], v[1]
    c, s = jnp.cos(theta), jnp.sin(theta)
    j_pitch = params["J_bc"] + params["m"] * params["r_c"]**2 + params["m"] * params["h"]**2
    j_yaw = params["J_bc"] * c**2 + params["m"] * (params["r_c"] * c - params["h"] * s) ** 2 + params["J_s"]
    return 0.5 * j_pitch * w_t**2 + 0.5 * j_yaw * w_p**2


def potential_energy(params, x):
    """P(x) = m g (r_c sin theta + h cos theta) [J], zero at the pivot (Sec. 2.4)."""
    theta = x[0]
    return params["m"] * params["g"] * (params["r_c"] * jnp.sin(theta) + params["h"] * jnp.cos(theta))


def helicopter_lagrangian(x, v, params):
    """L = K - P [J] of the helicopter, in the signature :func:`euler_lagrange_acceleration` takes."""
    return kinetic_energy(params, x, v) - potential_energy(params, x)


def mass_matrix(lagrangian: Callable, x, v, params):
    """M = d^2 L / dv^2, shape (n, n)."""
    return jax.hessian(lagrangian, argnums=1)(x, v, params)


def momenta(lagrangian: Callable, x, v, params):
    """Generalized momenta p = dL/dv, shape (n,)."""
    return jax.grad(lagrangian, argnums=1)(x, v, params)


def euler_lagrange_acceleration(lagrangian: Callable, x, v, params, force):
    """dv/dt from ``M(x) dv/dt = dL/dx - (dp/dx) v + F`` (paper Sec. 2.7).

    Parameters
    ----------
    lagrangian : callable
        ``L(x, v, params) -> scalar`` [J].
    x, v : arrays, shape (n,)
        Generalized coordinates and velocities.
    params : pytree
        Passed through to ``lagrangian``.
    force : array, shape (n,)
        Generalized force F.

    Returns
    -------
    array, shape (n,)
        Generalized accelerations.
    """
    dl_dx = jax.grad(lagrangian, argnums=0)(x, v, params)
    dp_dx = jax.jacfwd(momenta, argnums=1)(lagrangian, x, v, params)
    m = mass_matrix(lagrangian, x, v, params)
    return jnp.linalg.solve(m, dl_dx - dp_dx @ v + force)
