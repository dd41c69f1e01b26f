"""The least-squares stage of the MAP search, and the start grid it screens.

:func:`least_squares_fit` is Levenberg-Marquardt on the sampling coordinates and the
initial state, residuals from the one likelihood with fixed scales :data:`LSQ_SIGMA` plus
Gaussian prior terms: a Gauss-Newton method handles the very different scales of the
parameters in a few steps, where a quasi-Newton method on the full posterior stalls.
:func:`grid_start` screens the values a model's terms declare as separating the basins of
a fit (:meth:`heli_uq.model.HeliModel.start_grid`, e.g. a dead band's width between two
voltage levels) and gives one more start where a local fit would not go.  Both serve
:func:`heli_uq.inference.multistart.map_starts`.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from heli_uq.inference.levenberg import masked_least_squares
from heli_uq.model.tables import X0_NAMES
from heli_uq.probability.likelihood import whitened_residuals
from heli_uq.probability.problem import Problem

__all__ = ["least_squares_fit", "x0_guess", "grid_start", "LSQ_SIGMA", "GRID_STEPS", "GRID_GAIN",
           "FAILED_RESIDUAL"]  # fmt: skip

#: Residual scales [rad] (theta, psi) of the least-squares stage that precedes the MAP.
LSQ_SIGMA = (0.02, 0.1)
#: Residual of a sample whose simulation failed in the least-squares stage.
FAILED_RESIDUAL = 1e6
#: Levenberg-Marquardt steps that fit the other coordinates to each value of a start grid
#: (:func:`grid_start`).
GRID_STEPS = 10
#: A grid start is added when its screened cost is below this fraction of the first start's.
GRID_GAIN = 0.9


def least_squares_fit(problem: Problem, *, max_steps: int = 100):
    """A compiled ``fit(z0, x0, sigma=LSQ_SIGMA) -> (z, x0, cost)``: Levenberg-Marquardt of
    all coordinates ``z`` and the free initial-state entries on the training window, the
    residuals of (theta, psi) divided by ``sigma`` [rad] (module docstring)."""
    coords = problem.coords
    n, d = problem.n_train, coords.dim
    y = jnp.asarray(problem.y[:n])
    mu, sd = (jnp.asarray(a) for a in coords.prior_moments())
    x0_priors = problem.x0_priors()
    x0_mu = jnp.asarray([p.a for p in x0_priors])
    x0_sd = jnp.asarray([p.b if p.free else 1.0 for p in x0_priors])

    def residuals(v, sigma):
        z, x_init = v[:d], v[d:]
        phys = coords.to_physical(z)
        sol = problem.solve(phys, x_init, n, gradients="autodiff")
        r = whitened_residuals(sol.ys[:, :2], y, sigma).ravel()
        r = jnp.where(jnp.isfinite(r), r, FAILED_RESIDUAL)
        w = coords.prior_coordinates(z)
        return jnp.concatenate([r, (w - mu) / sd, (x_init - x0_mu) / x0_sd])

    fixed = jnp.asarray([False] * d + [not p.free for p in x0_priors])

    @jax.jit
    def compiled(z0, x0, sigma):
        v0 = jnp.concatenate([jnp.asarray(z0), jnp.asarray(x0)])
        v, cost = masked_least_squares(lambda v: residuals(v, sigma), v0, fixed, v0, max_steps)
        return v[:d], v[d:], cost

    def fit(z0, x0, sigma=LSQ_SIGMA):
        return compiled(z0, x0, jnp.asarray(sigma, dtype=jnp.float64))

    return fit


def x0_guess(problem: Problem, guess: dict | None = None) -> np.ndarray:
    """The initial state (4,) a least-squares fit starts from: the initial-state priors'
    centres (the first measured angles and the record's initial rates by default,
    :attr:`Problem.record_start`; a fixed value where fixed), or, for a free entry that
    ``guess`` (physical values by name, e.g. a fit of a nearby model) carries as a finite
    number, that value."""
    guess = {} if guess is None else guess
    out = []
    for name, prior in zip(X0_NAMES, problem.x0_priors()):
        value = float(guess.get(name, np.nan)) if prior.free else np.nan
        out.append(value if np.isfinite(value) else prior.a)
    return np.array(out)


def grid_start(problem: Problem, params: dict, *, log=None) -> dict | None:
    """One more MAP start for a model whose terms declare a start grid, or None.

    For each free parameter of :meth:`HeliModel.start_grid` on the training window's
    voltages (a dead band's width: one value between each two voltage levels), ``params``
    with that parameter at each grid value is fitted by :data:`GRID_STEPS`
    Levenberg-Marquardt steps (which refit the gains to it), and the value with the lowest
    cost kept.  The start is returned if its cost is below :data:`GRID_GAIN` times that of
    ``params`` screened the same way, i.e. if the grid found a better basin than the one
    ``params`` starts in.
    """
    grid = {k: v for k, v in problem.model.start_grid(problem.u[: problem.n_train]).items()
            if k in problem.coords.free}  # fmt: skip
    if not grid:
        return None
    short = least_squares_fit(problem, max_steps=GRID_STEPS)
    x0 = x0_guess(problem)

    def cost(trial):
        value = float(short(problem.coords.from_physical(trial), x0)[2])
        return value if np.isfinite(value) else np.inf

    own = cost(params)
    out = dict(params)
    for name, values in grid.items():
        costs = [cost({**params, name: float(v)}) for v in values]
        best = int(np.argmin(costs))
        if costs[best] < GRID_GAIN * own:
            out[name] = float(values[best])
            if log is not None:
                log(f"MAP grid start: {name} = {values[best]:.4g} (best of {len(values)} screened; "
                    f"cost {costs[best]:.4g} against {own:.4g} at {params[name]:.4g})")  # fmt: skip
    return out if out != params else None
