"""The map from NUTS's coordinates ``w`` to the sampler coordinates ``x``.

``x = g(y_map + L w)``: ``L L^T`` is the Laplace covariance at the MAP (mapped to ``y``),
so the posterior in ``w`` is close to ``N(0, I)``, and ``g`` acts coordinate-wise:

* the identity for most coordinates;
* ``x_i = x_map_i + s_i (log softplus(y_i) - log softplus(c_i))`` for a coordinate with a
  *wall* (:class:`Wall`: index ``i``, side ``s_i = +1`` above the MAP or ``-1`` below, knee
  ``c_i``), with ``y_map_i = c_i`` (so ``x = x_map``).  For a log coordinate
  ``x = log r`` this makes ``r`` (``s = +1``) or ``1 / r`` (``s = -1``) about linear in
  ``y`` on the wall side and keeps ``log r`` on the other.

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

**Walls below, and walls along a ridge.**  Where ``J_s`` dominates the yaw inertia (a
yaw friction record), the angles see ``1 / J_s`` (the gyroscopic coupling is
``M22'(theta) / M22``), and the initial yaw rate compensates it along a ridge that is
straight in ``1 / J_s`` and bent in ``log J_s``.  The conditional probe (the others at
the MAP) sees nothing, the ridge is a quartic wall along the coordinate's *marginal*
direction: on a 92 s yaw friction record the log density fell by 80 and 27 nats at -+2
marginal standard deviations (a Gaussian: 2) and NUTS took 16-30 leapfrog steps per draw
(about 50 in warm-up).  :func:`choose_walls` therefore probes every log coordinate of a
positive parameter along its marginal direction and tries the maps of :data:`WALL_KINDS`
where the log density is not Gaussian; there the reciprocal map (``s = -1``, ``c = 4``)
brought the rises to 2.1 and 2.5 nats.

``g`` is a smooth bijection of the real line and the potential includes
``-sum log g'(y_i)``, so the target distribution is exactly the same whichever
coordinates are chosen; the choice only changes how fast NUTS explores it.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["SamplerMap", "Wall", "choose_walls", "find_walls", "WALL_RISE", "WALL_ASYMMETRY",
           "WALL_PROBE", "WALL_KINDS", "MARGINAL_PROBES", "WALL_MISMATCH", "WALL_GAIN",
           "MAX_MARGINAL_WALLS"]  # fmt: skip

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
#: Probes [marginal standard deviations] of :func:`choose_walls`.
MARGINAL_PROBES = (-2.0, -1.0, 1.0, 2.0)
#: A coordinate's marginal direction is not Gaussian when the rises of ``-log p`` at the
#: probes differ from ``k^2 / 2`` by more than this in all [nats] (their sum is 5 nats).
WALL_MISMATCH = 4.0
#: A wall is kept when it cuts the coordinate's mismatch at least this many times.
WALL_GAIN = 2.0
#: Walls :func:`choose_walls` adds at most (each costs a round of probes).
MAX_MARGINAL_WALLS = 2
#: ``(side, knee)`` of the walls tried: ``r`` or ``1 / r`` linear near the MAP (knee 4:
#: ``softplus`` within 2 % of linear above the MAP) or with the knee at the MAP.
WALL_KINDS = ((1.0, 4.0), (-1.0, 4.0), (1.0, _Y0), (-1.0, _Y0))


class Wall(NamedTuple):
    """A coordinate mapped by ``x = x_map + side (log softplus(y) - log softplus(knee))``."""

    index: int
    #: ``+1``: the wall is above the MAP (``r`` linear in ``y``); ``-1``: below (``1 / r``).
    side: float = 1.0
    #: ``y`` at the MAP.
    knee: float = _Y0


def _as_wall(w) -> Wall:
    """A :class:`Wall` from an index (a wall above, knee at ``softplus = 1``; runs saved
    before walls had sides) or a ``(index, side, knee)`` sequence (JSON)."""
    if isinstance(w, (int, np.integer)):
        return Wall(int(w))
    i, side, knee = w
    return Wall(int(i), float(side), float(knee))


def _log_softplus(y):
    safe = jnp.maximum(y, _Y_LINEAR)
    return jnp.where(y > _Y_LINEAR, jnp.log(jax.nn.softplus(safe)), y)


def find_walls(potential, x_map, covariance) -> tuple[int, ...]:
    """Indices of the coordinates whose posterior has a one-sided wall *above* the MAP.

    For each coordinate ``i``, the potential (``-log p``) at ``x_map +- WALL_PROBE * s_i
    e_i`` (the others at the MAP; ``s_i = 1 / sqrt(P_ii)``, ``P`` the inverse of
    ``covariance``, the conditional standard deviation) is compared with its value at
    the MAP: a wall rises by more than :data:`WALL_RISE` upwards and by more than
    :data:`WALL_ASYMMETRY` times the rise downwards.  Walls below the MAP, and walls that
    only a move along a ridge meets, are :func:`choose_walls`'s.

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


def _marginal_mismatch(potential, smap: SamplerMap, i: int, p0: float) -> float:
    """``sum_k |rise_k - k^2 / 2|`` [nats] of ``-log p`` (with the map's log-Jacobian) at
    :data:`MARGINAL_PROBES` marginal standard deviations of ``y_i`` from the MAP, along the
    direction in which the Laplace approximation moves the other coordinates with it
    (``inf`` if a probe is not finite).  ``p0``: ``potential`` at the MAP."""
    p0 = p0 - float(smap.x_and_log_det(jnp.zeros(smap.x_map.size))[1])  # -log p in w at w = 0
    row = smap.lower[i]  # w = k L^T e_i / |L^T e_i| moves y along cov_y e_i / sd_i
    unit = row / np.linalg.norm(row)
    total = 0.0
    for k in MARGINAL_PROBES:
        x, log_det = smap.x_and_log_det(jnp.asarray(k * unit))
        value = float(potential(x)) - float(log_det) - p0
        if not np.isfinite(value):
            return math.inf
        total += abs(value - 0.5 * k * k)
    return total


def choose_walls(potential, x_map, covariance, candidates=None) -> tuple[Wall, ...]:
    """The walls of the sampler map: :func:`find_walls`, then walls along ridges.

    After the conditional test (walls above the MAP, knee at ``softplus = 1``), each
    coordinate of ``candidates`` (indices; default all) is probed along its marginal
    direction (:func:`_marginal_mismatch`).  The maps make ``r`` or ``1 / r`` linear, so
    they are meant for log coordinates ``x = log r`` of positive parameters (NUTS passes
    those; a network weight's posterior is not Gaussian for other reasons, its sign and
    permutation symmetries).  The worst candidate whose mismatch exceeds
    :data:`WALL_MISMATCH` gets each wall of
    :data:`WALL_KINDS` in turn, and keeps the best if it cuts its mismatch
    :data:`WALL_GAIN` times; at most :data:`MAX_MARGINAL_WALLS` rounds, each with the walls
    kept so far.  About ``4 d`` evaluations of ``potential`` per round (``d``
    coordinates), none compiled anew.  The arguments are :func:`find_walls`'s: the
    compiled potential, the MAP ``(d,)`` and its Laplace covariance ``(d, d)``.

    Returns
    -------
    tuple of Wall
    """
    x_map = np.asarray(x_map, dtype=float)
    walls = [Wall(i) for i in find_walls(potential, x_map, covariance)]
    allowed = set(range(x_map.size) if candidates is None else candidates)
    tried = {w.index for w in walls} | (set(range(x_map.size)) - allowed)
    p0 = float(potential(jnp.asarray(x_map)))
    scores = None
    for _ in range(MAX_MARGINAL_WALLS):
        if scores is None:  # the probes of the walls kept so far (again only after a new wall)
            smap = SamplerMap(x_map, covariance, tuple(walls))
            scores = [math.inf if i in tried else _marginal_mismatch(potential, smap, i, p0)
                      for i in range(x_map.size)]  # fmt: skip
        free = [i for i in range(x_map.size) if i not in tried and scores[i] > WALL_MISMATCH]
        if not free:
            break
        i = max(free, key=lambda j: scores[j])
        tried.add(i)
        best = (math.inf, None)
        for side, knee in WALL_KINDS:
            trial = SamplerMap(x_map, covariance, (*walls, Wall(i, side, knee)))
            score = _marginal_mismatch(potential, trial, i, p0)
            if score < best[0]:
                best = (score, Wall(i, side, knee))
        if best[0] * WALL_GAIN < scores[i]:
            walls.append(best[1])
            scores = None
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
    walls : tuple of Wall or int
        Coordinates that get the ``log softplus`` map (an ``int``: a wall above the MAP
        with its knee at ``softplus = 1``, as runs saved it before walls had sides).
    """

    x_map: np.ndarray
    covariance: np.ndarray
    walls: tuple = ()

    def __post_init__(self):
        x_map = np.asarray(self.x_map, dtype=float)
        cov = np.asarray(self.covariance, dtype=float)
        walls = tuple(_as_wall(w) for w in self.walls)
        side, knee = np.zeros(x_map.size), np.zeros(x_map.size)
        for w in walls:
            side[w.index], knee[w.index] = w.side, w.knee
        mask = side != 0.0
        log_knee = np.log(np.logaddexp(0.0, knee))  # log softplus
        # dx/dy at y_map: side * sigmoid(knee) / softplus(knee) (1 - 1/e at softplus = 1).
        slope = np.where(mask, side / (1.0 + np.exp(-knee)) / np.exp(log_knee), 1.0)
        cov_y = cov / np.outer(slope, slope)
        object.__setattr__(self, "x_map", x_map)
        object.__setattr__(self, "walls", walls)
        object.__setattr__(self, "mask", mask)
        object.__setattr__(self, "side", side)
        object.__setattr__(self, "log_knee", np.where(mask, log_knee, 0.0))
        object.__setattr__(self, "y_map", np.where(mask, knee, x_map))
        object.__setattr__(self, "lower", np.linalg.cholesky(0.5 * (cov_y + cov_y.T)))

    @classmethod
    def from_info(cls, info: dict) -> SamplerMap:
        """The map of a run's start information (``x_map``, ``covariance``, ``walls``)."""
        return cls(info["x_map"], info["covariance"], tuple(info.get("walls", ())))

    @property
    def indices(self) -> tuple[int, ...]:
        """The wall coordinates' indices."""
        return tuple(w.index for w in self.walls)

    def x_and_log_det(self, w):
        """``(x, log |dx/dw|)`` up to the constant ``log |det L|``; ``w`` shape (d,)."""
        y = jnp.asarray(self.y_map) + jnp.asarray(self.lower) @ w
        mask = jnp.asarray(self.mask)
        log_r = _log_softplus(y) - jnp.asarray(self.log_knee)
        x = jnp.where(mask, jnp.asarray(self.x_map) + jnp.asarray(self.side) * log_r, y)
        # log |g'(y)| = log sigmoid(y) - log softplus(y)
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
