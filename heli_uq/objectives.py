"""Fit measures between simulated and measured angles."""

from __future__ import annotations

import jax.numpy as jnp

__all__ = ["loss_v"]


def loss_v(ys, y_data):
    """Paper Eq. 1: ``V = 1/N sum_k (theta_k - theta_k^d)^2 + (psi_k - psi_k^d)^2`` [rad^2].

    Parameters
    ----------
    ys : array, shape (N, 4) or (N, 2)
        Simulated states (only the first two columns, theta and psi, are used).
    y_data : array, shape (N, 2)
        Measured (theta, psi) [rad].
    """
    r = jnp.asarray(ys)[:, :2] - jnp.asarray(y_data)
    return jnp.mean(jnp.sum(r * r, axis=1))
