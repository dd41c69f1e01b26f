"""The one likelihood of the package, and the paper's loss V.

Every stage that scores a simulation against a record calls these functions: the
numpyro model (NUTS, emcee, prediction), the least-squares stage of the MAP, the
maximum-likelihood fit and Fisher information of the identifiability report, and the
pointwise log likelihood stored in the results.

Given simulated angles ``sim`` and measured ``y`` (both (N, 2) [rad]) and the error model
(:mod:`heli_uq.probability.noise`: residual sd ``sigma`` (2,), for AR(1) ``rho`` (2,),
and for a timing error its sd ``timing`` (2,) [s] with the simulated rates ``rate`` (N, 2)
[rad/s]), the log density factorises into one-step-ahead conditionals
``y_k | y_{k-1} ~ N(loc_k, scale_k)``, so

* :func:`whitened_residuals` are ``(y - loc) / scale`` (the least-squares residuals),
* :func:`pointwise_log_likelihood` is ``-r^2/2 - log scale - log(2 pi)/2`` per sample and
  output, and its sum is the log likelihood.
"""

from __future__ import annotations

import jax.numpy as jnp

from heli_uq.probability.noise import conditional_moments

__all__ = ["loss_v", "whitened_residuals", "pointwise_log_likelihood", "log_likelihood"]


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


def whitened_residuals(sim, y, sigma, rho=None, timing=None, rate=None):
    """``(y_k - E[y_k | y_{k-1}]) / sd_k``, shape (N, 2), under the error model."""
    loc, scale = conditional_moments(sim, y, sigma, rho, timing, rate)
    return (y - loc) / scale


def pointwise_log_likelihood(sim, y, sigma, rho=None, timing=None, rate=None):
    """Log density of each observation given the past, shape (N, 2); sums to the joint."""
    loc, scale = conditional_moments(sim, y, sigma, rho, timing, rate)
    r = (y - loc) / scale
    return -0.5 * r * r - jnp.log(scale) - 0.5 * jnp.log(2.0 * jnp.pi)


def log_likelihood(sim, y, sigma, rho=None, timing=None, rate=None):
    """The log likelihood of the measured angles ``y`` (N, 2) given ``sim`` (N, 2)."""
    return jnp.sum(pointwise_log_likelihood(sim, y, sigma, rho, timing, rate))
