"""Error models for the angle residuals: independent Gaussian and AR(1), both O(N), each
with a constant scale or with a timing error.

AR(1) per output: ``e_k = s_k eta_k`` with the unit process ``eta_0 ~ N(0, 1)``,
``eta_k = rho eta_{k-1} + sqrt(1 - rho^2) xi_k``, ``xi_k ~ N(0, 1)``: marginal sd ``s_k``
and correlation ``rho^|i-j|``.  Its log density factorises into one-step-ahead
conditionals, which is what :func:`conditional_moments` returns;
:mod:`heli_uq.probability.likelihood` builds the one likelihood of the package from it.
Independent errors are ``rho = 0``.

**The timing error** (``"iid+timing"``, ``"ar1+timing"``).  A simulation that is right but
early or late by ``epsilon`` seconds misses the angle by ``omega(t) epsilon`` to first
order, with ``omega`` the simulated rate.  With ``epsilon ~ N(0, timing^2)`` on top of a
constant scale ``sigma`` the marginal sd is ``s_k = sqrt(sigma^2 + (timing omega_k)^2)``
(:func:`marginal_sd`): wide while the simulation swings, narrow while it holds still, which
is where a rigid-body model that gets the stick phases right and the swings' timing and
size wrong is right and wrong.  ``timing`` [s] per output is a parameter of the error
model, fitted with the others.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import lax

__all__ = ["ERROR_MODELS", "TIMING", "error_parts", "marginal_sd", "conditional_moments",
           "ar1_noise"]  # fmt: skip

#: Suffix of the error models with a timing error.
TIMING = "+timing"
ERROR_MODELS = ("iid", "ar1", "iid" + TIMING, "ar1" + TIMING)


def error_parts(error: str) -> tuple[bool, bool]:
    """``(ar1, timing)`` of an error model's name (one of :data:`ERROR_MODELS`)."""
    return error.startswith("ar1"), error.endswith(TIMING)


def marginal_sd(sigma, timing=None, rate=None):
    """The residuals' marginal sd [rad]: ``sigma`` (2,), or with a timing error
    ``sqrt(sigma^2 + (timing rate)^2)`` (N, 2) for ``timing`` (2,) [s] and the simulated
    rates ``rate`` (N, 2) [rad/s]."""
    if timing is None:
        return sigma
    return jnp.sqrt(sigma * sigma + (timing * rate) ** 2)


def conditional_moments(sim, y, sigma, rho=None, timing=None, rate=None):
    """Mean and sd of each observation given the previous one.

    Parameters
    ----------
    sim : array, shape (N, 2)
        Simulated angles [rad].
    y : array, shape (N, 2)
        Observed angles [rad].
    sigma : array, shape (2,)
        Residual sd per output [rad] (the marginal sd without a timing error).
    rho : array, shape (2,), optional
        AR(1) coefficient per output; ``None`` means independent errors.
    timing, rate : arrays, shapes (2,) [s] and (N, 2) [rad/s], optional
        The timing error's sd and the simulated rates (:func:`marginal_sd`); ``None``
        means a constant scale.

    Returns
    -------
    loc, scale : arrays, shape (N, 2)
    """
    s = jnp.broadcast_to(marginal_sd(sigma, timing, rate), sim.shape)
    if rho is None:
        return sim, s
    resid_prev = y[:-1] - sim[:-1]
    loc = jnp.concatenate([sim[:1], sim[1:] + rho * (s[1:] / s[:-1]) * resid_prev], axis=0)
    scale = jnp.concatenate([s[:1], s[1:] * jnp.sqrt(1.0 - rho * rho)], axis=0)
    return loc, scale


def ar1_noise(key, n: int, sigma, rho=None, timing=None, rate=None):
    """Draw residuals of shape (n, 2) from the error model (iid when ``rho`` is None; a
    timing error when ``timing`` and ``rate`` (n, 2) are given, :func:`marginal_sd`)."""
    xi = jax.random.normal(key, (n, 2))
    if rho is None:
        eta = xi
    else:
        innov = jnp.sqrt(1.0 - rho * rho) * xi[1:]

        def body(e, inn):
            e = rho * e + inn
            return e, e

        _, rest = lax.scan(body, xi[0], innov)
        eta = jnp.concatenate([xi[:1], rest], axis=0)
    return marginal_sd(sigma, timing, rate) * eta
