"""The NUTS metric: the Laplace covariance, rescaled along its axes to the posterior's width.

The Laplace covariance ``H^-1`` describes the log posterior's curvature *at* the MAP.  A
stiff term (sharp dry friction) makes the log posterior far from quadratic on the scale
of its own width: on a synthetic record with pitch friction hidden (``F_c = 0.005`` N m,
the published inputs), three of the 18 axes of ``H^-1`` rose by 15-16 nats at one
Laplace sd instead of 0.5, and by 900-1500 at three.  NUTS in coordinates whitened by
``H^-1`` then adapts a small step size (0.06-0.11) and fills its trees (57 % of the
draws at depth 6; R-hat 1.13, bulk ESS 17).

:func:`level_scaled_covariance` walks along each eigenvector ``v_j`` of the covariance
(sd ``s_j``) to the distance ``d_j`` at which ``-log p`` has risen by :data:`LEVEL_NATS`
(2 nats: a Gaussian's 2 sd), on both sides, and replaces ``s_j`` by ``r_j s_j`` with
``r_j = d_j / (2 s_j)`` (the mean of the two sides) when ``r_j`` is outside
:data:`KEEP_RANGE`.  On a quadratic log posterior every ``r_j`` is 1 and the covariance
is returned as it was (so a run on a well-behaved posterior is unchanged).  For a quartic
``exp(-x^4/4)`` the 2-nat level gives 0.84, the true sd 0.82 (the 0.5-nat level: 1.19).

On the friction record above (NUTS 2 x (150 + 350), depth 6, no mass-matrix
adaptation, two cores):

==================================  ======  =============  ============  ======  ========
metric                              wall    leapfrog/draw  at depth 6    R-hat   bulk ESS
==================================  ======  =============  ============  ======  ========
Laplace covariance                  1053 s  49             57 %          1.13    17
0.5-nat level (r = 0.41-0.69)       719 s   37             31 %          1.04    97
2-nat level (r = 0.30-0.53)         508 s   25             10 %          1.04    62
Laplace + dense adaptation          1095 s  62             97 %          1.06    26
==================================  ======  =============  ============  ======  ========

The worst-mixing coordinate in every row is the initial pitch rate, whose marginal sd is
45 times its conditional one.

Cost: about 18 log-density evaluations per axis (bisection in ``log r``), about 3 s on
that record; not measured for a model with a neural term (d ~ 30-150).
"""

from __future__ import annotations

import numpy as np

__all__ = ["level_scaled_covariance", "level_distance", "LEVEL_NATS", "KEEP_RANGE", "R_LIMITS"]

#: Rise of ``-log p`` [nats] that defines the width along an axis: 2 nats is a Gaussian's
#: 2 sd, where most of the mass is; the distance is divided by 2 to give an sd (module
#: docstring: the 0.5-nat level, a Gaussian's 1 sd, left the sampler slower).
LEVEL_NATS = 2.0
#: Axes whose level distance ``r`` (in Laplace sd) lies in this range keep their Laplace sd.
KEEP_RANGE = (0.8, 1.25)
#: The search for ``r`` stops at these limits [Laplace sd].
R_LIMITS = (1.0 / 16.0, 8.0)
#: Bisection steps in ``log r`` once the level is bracketed (``r`` to within 2^(1/64)).
BISECTIONS = 6


def level_distance(potential, x: np.ndarray, direction: np.ndarray, value: float) -> float:
    """Distance ``r`` [units of ``direction``] from ``x`` along ``direction`` at which
    ``potential`` has risen by :data:`LEVEL_NATS` over ``value`` (bracketed by halving or
    doubling from 1, then bisected in ``log r``; a non-finite potential counts as above the
    level; clipped to :data:`R_LIMITS`).

    Parameters
    ----------
    potential : callable
        ``-log p`` of a point, shape (d,).
    x, direction : arrays, shape (d,)
    value : float
        ``potential(x)``.
    """

    def above(r: float) -> bool:
        rise = float(potential(x + r * direction)) - value
        return not rise < LEVEL_NATS  # NaN and inf count as above

    lo_limit, hi_limit = R_LIMITS
    if above(1.0):
        hi, lo = 1.0, 0.5
        while above(lo):
            if lo <= lo_limit:
                return lo_limit
            hi, lo = lo, lo / 2.0
    else:
        lo, hi = 1.0, 2.0
        while not above(hi):
            if hi >= hi_limit:
                return hi_limit
            lo, hi = hi, hi * 2.0
    for _ in range(BISECTIONS):
        mid = float(np.sqrt(lo * hi))
        lo, hi = (lo, mid) if above(mid) else (mid, hi)
    return float(np.sqrt(lo * hi))


def level_scaled_covariance(potential, x: np.ndarray, value: float,
                            covariance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """The covariance with each eigen-axis rescaled to the posterior's level width (module
    docstring).

    Parameters
    ----------
    potential : callable
        ``-log p`` of a point, shape (d,) (e.g. a density's ``potential_jit``).
    x : array, shape (d,)
        The MAP.
    value : float
        ``potential(x)``.
    covariance : array, shape (d, d)
        The Laplace covariance at ``x``.

    Returns
    -------
    covariance : array, shape (d, d)
        Same eigenvectors, each sd multiplied by its factor.
    factors : array, shape (d,)
        The factor per eigen-axis (ascending eigenvalue order), 1 where kept.
    """
    x = np.asarray(x, dtype=float)
    eigenvalues, vectors = np.linalg.eigh(np.asarray(covariance, dtype=float))
    sds = np.sqrt(np.maximum(eigenvalues, 0.0))
    factors = np.ones_like(sds)
    for j, (sd, v) in enumerate(zip(sds, vectors.T, strict=True)):
        r = 0.5 * (level_distance(potential, x, sd * v, value) + level_distance(potential, x, -sd * v, value))
        r /= np.sqrt(2.0 * LEVEL_NATS)  # a Gaussian's level distance in sd
        if not KEEP_RANGE[0] <= r <= KEEP_RANGE[1]:
            factors[j] = r
    if np.all(factors == 1.0):  # a quadratic posterior: the Laplace covariance as it was
        return np.asarray(covariance), factors
    scaled = (vectors * (sds * factors) ** 2) @ vectors.T
    return 0.5 * (scaled + scaled.T), factors
