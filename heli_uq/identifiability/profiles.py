"""Profile likelihoods of every coordinate of ``w``, and their classification.

For coordinate ``j`` the profile is ``PL(c) = min over w with w_j = c of -log L(w)``
(the error model of :mod:`heli_uq.identifiability.fisher`, noise held fixed).  It is traced outwards
from the fit on each side, every point re-optimising all other coordinates
(Levenberg-Marquardt, warm-started at the previous point plus the Gauss-Newton
prediction ``dw_rest = -J_rest^+ J_j dc``, which follows a curved valley and moves
exactly along a structural null direction), until the increase exceeds the 95 %
threshold ``chi2_1(0.95) / 2 = 1.92`` or the prior range is reached.

Classification (Raue et al. 2009, with the structural analysis as tie-breaker):

* ``identifiable``: the profile crosses the threshold on both sides; ``ci95`` is the
  interval between the (linearly interpolated) crossings.
* ``structurally_non_identifiable``: the profile is flat (increase below
  :data:`FLAT_DELTA` over the whole prior range on both sides) *and* the coordinate has
  a loading on the structural null space.
* ``practically_non_identifiable``: anything else: the profile crosses on one side only,
  or rises but stays under the threshold within the prior range, or is flat although the
  sensitivities have full rank (a very weakly identified direction, e.g. r_c with h ~ 0).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
from scipy import stats

from heli_uq.identifiability.fisher import WhitenedResiduals
from heli_uq.inference.levenberg import masked_least_squares

__all__ = ["THRESHOLD_95", "FLAT_DELTA", "CLASSES", "Profile", "profile_likelihood", "classify"]

#: Increase of -log L that bounds a 95 % profile-likelihood interval (one parameter).
THRESHOLD_95 = 0.5 * float(stats.chi2.ppf(0.95, 1))

#: A profile whose increase stays below this over the prior range is "flat" [log-likelihood units].
FLAT_DELTA = 0.01

#: Stop a side once the increase exceeds this multiple of the threshold.
OVERSHOOT = 2.0

#: A first point above this multiple of the threshold is retried with a quarter of the step.
REFINE_ABOVE = 8.0

#: At most this many points per side, and Levenberg-Marquardt steps per point.
MAX_POINTS = 12
STEPS_PER_POINT = 20

#: Relative singular-value cut-off of the warm-start prediction (weaker directions are left
#: to the optimiser: predicting along them would amplify round-off into huge jumps).
PREDICTION_RCOND = 1e-6

CLASSES = ("identifiable", "practically_non_identifiable", "structurally_non_identifiable")


@dataclasses.dataclass(frozen=True)
class Profile:
    """One profile: ``values`` of the coordinate (sorted), ``delta`` = increase of -log L
    over the optimum, ``bounds`` (the prior range explored), the classification and the
    95 % interval (``None`` where the profile does not cross)."""

    name: str
    values: np.ndarray
    delta: np.ndarray
    bounds: tuple
    lower: float | None
    upper: float | None
    flat: bool
    classification: str = ""

    @property
    def ci95(self):
        return [self.lower, self.upper] if self.lower is not None and self.upper is not None else None


@jax.jit
def _costs(residuals, ws):
    return jax.vmap(lambda w: 0.5 * jnp.sum(residuals(w) ** 2))(ws)


def _backward_sweep(residuals, mask, side_points):
    """Re-optimise a non-monotone side from the outside in (each point warm-started at its
    outer neighbour's solution) and keep the lower cost: a point that rose above a later one
    was an optimiser failure, not a feature of the likelihood."""
    costs = np.array([c for _, c, _ in side_points])
    later_min = np.minimum.accumulate(costs[::-1])[::-1]
    if costs.size < 2 or not np.any(costs[:-1] > later_min[1:] + FLAT_DELTA):
        return [(t, c) for t, c, _ in side_points]
    out = [side_points[-1][:2]]
    w_outer = side_points[-1][2]
    for target, cost, w_fwd in side_points[-2::-1]:
        guess = np.asarray(w_outer).copy()
        guess[mask] = target
        w_new, c_new = masked_least_squares(residuals, jnp.asarray(guess), jnp.asarray(mask),
                                            jnp.asarray(guess), STEPS_PER_POINT)  # fmt: skip
        c_new = float(c_new)
        if np.isfinite(c_new) and c_new < cost:
            cost, w_fwd = c_new, np.asarray(w_new)
        out.append((target, cost))
        w_outer = w_fwd
    return out


def _crossing(c0, d0, c1, d1):
    """Coordinate between c0 (delta d0 <= threshold) and c1 (d1 > threshold) at the threshold."""
    if not np.isfinite(d1):
        return c1
    # Interpolate sqrt(delta), which is linear in c for a locally quadratic profile.
    r0, r1, rt = np.sqrt(max(d0, 0.0)), np.sqrt(d1), np.sqrt(THRESHOLD_95)
    return c0 + (rt - r0) * (c1 - c0) / (r1 - r0)


def profile_likelihood(residuals: WhitenedResiduals, w_hat, cost_hat: float, j: int,
                       bounds: tuple, step0: float, jac=None, null_basis=None) -> tuple:  # fmt: skip
    """Trace the profile of coordinate ``j`` within ``bounds``.

    Parameters
    ----------
    residuals : WhitenedResiduals
    w_hat : array, shape (P,)
        The fit.
    cost_hat : float
        ``0.5 |r(w_hat)|^2``.
    j : int
    bounds : (float, float)
        Range of ``w_j`` explored (the prior range).
    step0 : float
        First step (e.g. the Cramér-Rao standard error, capped by the range).
    jac : array, shape (2N, P), optional
        Whitened Jacobian at ``w_hat`` for the warm-start prediction.
    null_basis : array, shape (P, k), optional
        Null vectors at ``w_hat`` (the named directions, then an orthonormal basis): if
        ``w_j`` has a loading on one, moving along it is another warm start (exactly flat
        for a global invariance such as the common scaling), as is the smallest move
        within their span.

    Returns
    -------
    values, costs : ndarrays
        Coordinate values (sorted) and ``0.5 |r|^2`` at the profile points (incl. ``w_hat``).
    """
    w_hat = np.asarray(w_hat, dtype=float)
    p = w_hat.size
    mask = np.zeros(p, dtype=bool)
    mask[j] = True
    rest = ~mask
    if jac is None:
        jac = np.asarray(jax.jacfwd(residuals)(jnp.asarray(w_hat)))
    slope, *_ = np.linalg.lstsq(jac[:, rest], -jac[:, j], rcond=PREDICTION_RCOND)
    direction = np.zeros(p)
    direction[j] = 1.0
    direction[rest] = slope
    directions = [direction]
    if null_basis is not None and null_basis.size and np.linalg.norm(null_basis[j]) > 1e-6:
        u, sv, _ = np.linalg.svd(null_basis, full_matrices=False)
        q = u[:, sv > 1e-9 * sv[0]]  # orthonormal basis of the span
        directions.append(q @ (q[j] / np.sum(q[j] ** 2)))
        directions += [v / v[j] for v in null_basis.T if abs(v[j]) > 1e-6]
    points = [(w_hat[j], cost_hat)]
    for side in (-1.0, 1.0):
        limit = bounds[0] if side < 0 else bounds[1]
        w = w_hat.copy()
        step = step0
        prev = 0.0
        refinements = 0
        side_points = []
        for _ in range(MAX_POINTS):
            target = w[j] + side * step
            at_limit = (target - limit) * side >= 0
            target = limit if at_limit else target
            shifted = w.copy()
            shifted[j] = target
            # Start from the best of the Gauss-Newton prediction, the null-space move and the
            # plain shift: the prediction follows the valley but can overshoot along weakly
            # identified directions.
            guesses = np.stack([w + (target - w[j]) * d for d in directions] + [shifted])
            guess = guesses[int(np.argmin(np.asarray(_costs(residuals, jnp.asarray(guesses)))))]
            w_new, cost = masked_least_squares(residuals, jnp.asarray(guess), jnp.asarray(mask),
                                               jnp.asarray(guess), STEPS_PER_POINT)  # fmt: skip
            cost = float(cost)
            cost = cost if np.isfinite(cost) else np.inf
            side_points.append((target, cost, np.asarray(w_new)))
            delta = cost - cost_hat
            if delta > REFINE_ABOVE * THRESHOLD_95 and prev < THRESHOLD_95 and refinements < 6:
                # Overshot the threshold by far: retry closer, so the crossing is resolved.
                step = abs(target - w[j]) / 4.0
                refinements += 1
                continue
            if delta > OVERSHOOT * THRESHOLD_95 or at_limit:
                break
            w = np.asarray(w_new)
            increment = delta - prev
            prev = delta
            if increment < 0.1 * THRESHOLD_95:
                step *= 2.0
            elif increment > 0.5 * THRESHOLD_95:
                step *= 0.5
        side_points.sort(key=lambda point: side * point[0])  # outwards (refinements interleave)
        points += _backward_sweep(residuals, mask, side_points)
    points.sort()
    values = np.array([v for v, _ in points])
    costs = np.array([c for _, c in points])
    return values, costs


def classify(name: str, values, costs, bounds, null_loading: float, *, center: float) -> Profile:
    """Build the :class:`Profile` of one coordinate and classify it (see module docstring).

    ``costs`` are re-referenced to their minimum (the profile may find a slightly better
    optimum than the fit).  ``null_loading`` is the norm of the coordinate's unit vector
    projected on the structural null space (0 if none).
    """
    values = np.asarray(values, dtype=float)
    delta = np.asarray(costs, dtype=float) - np.min(costs)
    i0 = int(np.argmin(np.abs(values - center)))
    lower = upper = None
    for k in range(i0, 0, -1):
        if delta[k - 1] > THRESHOLD_95 >= delta[k]:
            lower = float(_crossing(values[k], delta[k], values[k - 1], delta[k - 1]))
            break
    for k in range(i0, len(values) - 1):
        if delta[k + 1] > THRESHOLD_95 >= delta[k]:
            upper = float(_crossing(values[k], delta[k], values[k + 1], delta[k + 1]))
            break
    flat = bool(np.all(np.isfinite(delta)) and np.max(delta) < FLAT_DELTA)
    if lower is not None and upper is not None:
        cls = "identifiable"
    elif flat and null_loading > 1e-6:
        cls = "structurally_non_identifiable"
    else:
        cls = "practically_non_identifiable"
    return Profile(name=name, values=values, delta=delta, bounds=tuple(map(float, bounds)),
                   lower=lower, upper=upper, flat=flat, classification=cls)  # fmt: skip
