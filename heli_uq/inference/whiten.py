"""The map from NUTS's coordinates ``w`` to the sampler coordinates ``x``.

``x = g(y_map + L w)``: ``L L^T`` is the Laplace covariance at the MAP (mapped to ``y``),
so the posterior in ``w`` is close to ``N(0, I)``, and ``g`` acts coordinate-wise:

* the identity for most coordinates;
* ``x_i = x_map_i + log softplus(y_i)`` for a coordinate with a *one-sided wall*
  (:func:`find_walls`), with ``y_map_i = log(e - 1)`` (``softplus = 1``, ``x = x_map``).

**Why the walls.**  A positive parameter the record identifies only from above (the rig
record says the rotor inertia ``J_s`` is small, not how small) has a posterior that, in
its log coordinate, is the prior's Gaussian tail on one side and an exponential wall on
the other: the likelihood sees ``r = exp(x)`` about linearly, so the log density falls
like ``exp(2 x)``.  On the full rig record the curvature of the whitened log density at
two standard deviations up ``log(J_s / M11)`` is 28 times that at the MAP (72 times at
three), and NUTS has to take steps small enough for the wall everywhere: step size
~0.2, 20 leapfrog steps per draw.  In ``y`` with ``r = r_map softplus(y)`` the wall side
is linear in ``r``, hence Gaussian, and the far side stays logarithmic: the whitened
curvature stays within 0.5-1.0 over +-3 standard deviations.

``g`` is a smooth bijection of the real line and the potential includes
``-sum log g'(y_i)``, so the target distribution is exactly the same whichever
coordinates are chosen; the choice only changes how fast NUTS explores it.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["SamplerMap", "find_walls", "WALL_RISE", "WALL_ASYMMETRY", "WALL_PROBE"]

#: Probe distance [conditional standard deviations at the MAP] of the wall test.
WALL_PROBE = 2.0
#: A coordinate has a wall if the log density falls by more than this [nats] at the
#: probe on one side (a Gaussian falls by ``WALL_PROBE**2 / 2 = 2``) ...
WALL_RISE = 6.0
#: ... and by more than this many times as much as on the other side.
WALL_ASYMMETRY = 3.0
#: ``y`` at which ``softplus(y) = 1``, i.e. ``x = x_map``.
_Y0 = math.log(math.e - 1.0)
#: Below this ``y``, ``log softplus(y) = y`` to double precision.
_Y_LINEAR = -35.0


def _log_softplus(y):
    safe = jnp.maximum(y, _Y_LINEAR)
    return jnp.where(y > _Y_LINEAR, jnp.log(jax.nn.softplus(safe)), y)


def find_walls(potential, x_map, covariance) -> tuple[int, ...]:
    """Indices of the coordinates whose posterior has a one-sided wall *above* the MAP.

    For each coordinate ``i``, the potential (``-log p``) at ``x_map +- WALL_PROBE * s_i
    e_i`` (the others at the MAP; ``s_i = 1 / sqrt(P_ii)``, ``P`` the inverse of
    ``covariance``, the conditional standard deviation) is compared with its value at
    the MAP: a wall rises by more than :data:`WALL_RISE` upwards and by more than
    :data:`WALL_ASYMMETRY` times the rise downwards.  Walls below the MAP are left alone:
    in a log coordinate the likelihood flattens towards zero, it does not steepen.

    Parameters
    ----------
    potential : callable
        ``x (d,) -> -log p`` (jit-compiled).
    x_map : array, shape (d,)
    covariance : array, shape (d, d)
    """
    x_map = np.asarray(x_map, dtype=float)
    precision = np.linalg.inv(0.5 * (covariance + np.transpose(covariance)))
    scale = 1.0 / np.sqrt(np.clip(np.diag(precision), 1e-300, None))
    p0 = float(potential(jnp.asarray(x_map)))
    walls = []
    for i in range(x_map.size):
        rises = []
        for sign in (1.0, -1.0):
            x = x_map.copy()
            x[i] += sign * WALL_PROBE * scale[i]
            value = float(potential(jnp.asarray(x)))
            rises.append(value - p0 if np.isfinite(value) else np.inf)
        up, down = rises
        if np.isfinite(down) and up > WALL_RISE and up > WALL_ASYMMETRY * max(down, 0.0):
            walls.append(i)
    return tuple(walls)


@dataclasses.dataclass(frozen=True, eq=False)
class SamplerMap:
    """``x = g(y_map + L w)`` (module docstring).

    Parameters
    ----------
    x_map : array, shape (d,)
        The MAP in sampler coordinates.
    covariance : array, shape (d, d)
        The Laplace covariance of ``x``.
    walls : tuple of int
        Coordinates that get the ``log softplus`` map.
    """

    x_map: np.ndarray
    covariance: np.ndarray
    walls: tuple = ()

    def __post_init__(self):
        x_map = np.asarray(self.x_map, dtype=float)
        cov = np.asarray(self.covariance, dtype=float)
        mask = np.zeros(x_map.size, bool)
        mask[list(self.walls)] = True
        # dx/dy at y_map: 1 - 1/e for a wall coordinate (sigmoid / softplus at _Y0).
        slope = np.where(mask, 1.0 - math.exp(-1.0), 1.0)
        cov_y = cov / np.outer(slope, slope)
        object.__setattr__(self, "x_map", x_map)
        object.__setattr__(self, "mask", mask)
        object.__setattr__(self, "y_map", np.where(mask, _Y0, x_map))
        object.__setattr__(self, "lower", np.linalg.cholesky(0.5 * (cov_y + cov_y.T)))

    @classmethod
    def from_info(cls, info: dict) -> SamplerMap:
        """The map of a run's start information (``x_map``, ``covariance``, ``walls``)."""
        return cls(info["x_map"], info["covariance"], tuple(info.get("walls", ())))

    def x_and_log_det(self, w):
        """``(x, log |dx/dw|)`` up to the constant ``log |det L|``; ``w`` shape (d,)."""
        y = jnp.asarray(self.y_map) + jnp.asarray(self.lower) @ w
        mask = jnp.asarray(self.mask)
        x = jnp.where(mask, jnp.asarray(self.x_map) + _log_softplus(y), y)
        # log g'(y) = log sigmoid(y) - log softplus(y)
        log_slope = jax.nn.log_sigmoid(y) - _log_softplus(y)
        return x, jnp.sum(jnp.where(mask, log_slope, 0.0))

    # Compiled once per map: every saved chunk of a run maps its draws with it.
    @functools.cached_property
    def _x_batched(self):
        return jax.jit(jax.vmap(lambda v: self.x_and_log_det(v)[0]))

    def x(self, w: np.ndarray) -> np.ndarray:
        """Sampler coordinates of ``w`` (..., d) (NumPy)."""
        w = np.asarray(w, dtype=float)
        x = self._x_batched(jnp.asarray(w.reshape(-1, w.shape[-1])))
        return np.asarray(x).reshape(w.shape)
