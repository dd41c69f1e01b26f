"""Error models for the angle residuals: independent Gaussian and AR(1), both O(N).

AR(1) per output: ``e_0 ~ N(0, s^2)``, ``e_k = rho e_{k-1} + sqrt(1 - rho^2) s xi_k`` with
``xi_k ~ N(0, 1)``: a stationary process with marginal sd ``s`` and correlation
``rho^|i-j|``.  Its log density factorises into one-step-ahead conditionals, which is
what :func:`conditional_moments` returns; :mod:`heli_uq.probability.likelihood` builds the
one likelihood of the package from it.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import lax

__all__ = ["ERROR_MODELS", "conditional_moments", "ar1_noise"]

ERROR_MODELS = ("iid", "ar1")


def conditional_moments(sim, y, sigma, rho=None):
    """Mean and sd of each observation given the previous one.

    Parameters
    ----------
    sim : array, shape (N, 2)
        Simulated angles [rad].
    y : array, shape (N, 2)
        Observed angles [rad].
    sigma : array, shape (2,)
        Marginal residual sd per output [rad].
    rho : array, shape (2,), optional
        AR(1) coefficient per output; ``None`` means independent errors.

    Returns
    -------
    loc, scale : arrays, shape (N, 2)
    """
    if rho is None:
        return sim, jnp.broadcast_to(sigma, sim.shape)
    resid_prev = y[:-1] - sim[:-1]
    loc = jnp.concatenate([sim[:1], sim[1:] + rho * resid_prev], axis=0)
    inner = jnp.broadcast_to(sigma * jnp.sqrt(1.0 - rho * rho), sim[1:].shape)
    scale = jnp.concatenate([jnp.broadcast_to(sigma, sim[:1].shape), inner], axis=0)
    return loc, scale


def ar1_noise(key, n: int, sigma, rho=None):
    """Draw residuals of shape (n, 2) from the error model (iid when ``rho`` is None)."""
    xi = jax.random.normal(key, (n, 2))
    if rho is None:
        return sigma * xi
    innov = jnp.sqrt(1.0 - rho * rho) * sigma * xi[1:]

    def body(e, inn):
        e = rho * e + inn
        return e, e

    _, rest = lax.scan(body, sigma * xi[0], innov)
    return jnp.concatenate([sigma * xi[:1], rest], axis=0)
