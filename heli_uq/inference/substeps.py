"""The RK4 substeps per sample a fit needs: at a parameter point (its stiffness), over a
set of starting guesses, and over the Laplace approximation's tail draws.

A stiff effect (sharp friction, a large damping) needs more substeps the larger its level;
:func:`heli_uq.inference.start.prepare_start` raises a problem's substeps with these
(:func:`cover_substeps`).
"""

from __future__ import annotations

import logging

import jax.numpy as jnp
import numpy as np

from heli_uq.inference.density import LogDensity, constrain_draws, log_density_setup
from heli_uq.inference.gaussian import gaussian_draws
from heli_uq.inference.map import laplace, newton_polish
from heli_uq.probability.problem import Problem
from heli_uq.simulation.stiffness import (
    MAX_SUBSTEPS,
    RK4_STABILITY,
    SMOOTHER_FRICTION,
    capped_substeps,
    damping_edge,
    default_substeps,
    edge_text,
    stiffness_rates,
    substeps_covering,
)

__all__ = ["TAIL_DRAWS", "EDGE_SUBSTEPS", "required_substeps", "decay_held", "map_need", "map_edge",
           "tail_substeps", "guess_substeps", "retry_substeps", "cover_substeps",
           "map_values"]  # fmt: skip

#: Laplace draws (seeded) whose stiffness the substeps must cover (their maximum is about
#: the 99.8 % quantile of the rate).  The output stage checks every posterior draw again
#: (:func:`heli_uq.simulation.stiffness.stiffness_check`).
TAIL_DRAWS = 256
#: Most substeps a fit pinned at the solver's limit (:func:`map_edge`) is raised to.  Its
#: MAP follows the limit: on a 131 s record with a hidden pitch friction the base model
#: needed 2, 4, 8, 16 and 32 substeps at 1, 2, 4, 8 and 16, ``-log p`` fell by 583, 335,
#: 178 and 48 nats, and each raise made it and every candidate nesting it slower (at 16 a
#: wrong candidate took 80 s, its least squares never converging at the limit).  So a MAP
#: found pinned is raised once, to this, and held there.  A viscous decay inside the limit
#: is not raised for (:func:`decay_held`), so the fits that nest a pinned one and are pinned
#: too are held at the same count: their comparison holds no solver difference.
EDGE_SUBSTEPS = 2
#: Why a pinned fit's substeps are held (the cap's warning).
EDGE_HELD = (f"more substeps move that limit with them, not the fit's answer, so a fit pinned there "
             f"is held at {EDGE_SUBSTEPS} (or at its problem's substeps, if more)")
#: ``r h`` up to this multiple of RK4's limit (2.785, rounded) counts as at the limit: a MAP
#: found there sits on it to rounding (``r h`` = 2.7854 on that record).
EDGE_ROUNDING = 1.001


def required_substeps(problem: Problem, params: dict, decay: bool = True) -> int:
    """Substeps the model needs at ``params`` on the fitting window (``decay`` False: its
    stiff terms but the viscous damping)."""
    return default_substeps(problem.model, params, problem.dt, thetas=problem.y[: problem.n_train, 0],
                            decay=decay)  # fmt: skip


def decay_held(problem: Problem, params: dict, substeps: int) -> bool:
    """True if a fit at ``params`` needs more than ``substeps`` only for its viscous decay,
    and that decay is stable at ``substeps`` (``r h`` inside RK4's limit, to rounding).  The
    solver then holds it: a linear mode inside the limit errs little (yaw damping at
    ``r h`` = 2.7: 1.3e-4 rad, :mod:`~heli_uq.simulation.stiffness`), and more substeps
    would only let a fit that imitates a missing torque by damping damp harder."""
    if required_substeps(problem, params, decay=False) > substeps:
        return False
    edge = damping_edge(problem.model, params, problem.dt, substeps, thetas=problem.y[: problem.n_train, 0])
    return edge is None or edge["rh"] <= EDGE_ROUNDING * RK4_STABILITY


def map_edge(problem: Problem, params: dict) -> dict | None:
    """The viscous decay of a fit at ``params`` pinned at RK4's stability limit on
    ``problem``'s substeps (:func:`heli_uq.simulation.stiffness.damping_edge`), or None."""
    return damping_edge(problem.model, params, problem.dt, problem.substeps,
                        thetas=problem.y[: problem.n_train, 0])  # fmt: skip


def map_need(problem: Problem, params: dict, edge: dict | None = None) -> tuple[int, dict | None]:
    """``(need, edge)``: the substeps a MAP at ``params`` needs (:func:`required_substeps`),
    capped, and its viscous decay pinned at the solver's limit (:func:`map_edge`), or the
    ``edge`` an earlier MAP of the same fit was pinned at, or None.

    A decay the solver holds (:func:`decay_held`) needs no raise.  The cap is
    :data:`MAX_SUBSTEPS`, or for a fit pinned at the limit :data:`EDGE_SUBSTEPS` (at least
    the problem's substeps).  Below the cap the need is capped silently: the MAP is raised
    to the cap and checked again, so the warning is given once, on the MAP that stays; at
    the cap it says the fit is pinned (or that an earlier MAP of it was, if the one at the
    cap is inside the limit), or suggests a smoother friction.
    """
    current = map_edge(problem, params)
    earlier = current is None and edge is not None  # pinned before a raise, inside the limit now
    edge = current or edge
    cap = MAX_SUBSTEPS if edge is None else max(EDGE_SUBSTEPS, problem.substeps)
    need = required_substeps(problem, params)
    if need > problem.substeps and edge is None and decay_held(problem, params, problem.substeps):
        return problem.substeps, None
    if need <= cap or problem.substeps < cap:
        return min(need, cap), edge
    hint = SMOOTHER_FRICTION if edge is None else f"{edge_text(edge)}; {EDGE_HELD}"
    if earlier:  # the warning is about the MAP that stays: say the edge was an earlier one's
        hint = (f"this fit's MAP at {edge['substeps']} substep(s) was pinned at the solver's limit, "
                f"its MAP at {problem.substeps} is inside it: {hint}")  # fmt: skip
    return capped_substeps(need, "the MAP", hint, cap), edge


def tail_substeps(problem: Problem, density: LogDensity, x_map, cov, seed: int = 0) -> int:
    """Substeps that cover the stiffness of :data:`TAIL_DRAWS` draws of ``N(x_map, cov)``
    (the sampler's unconstrained coordinates) on the fitting window."""
    rng = np.random.default_rng(seed)
    x = gaussian_draws(x_map, cov, TAIL_DRAWS, rng)
    draws = constrain_draws(density, x)
    fixed = {k: float(p.a) for k, p in problem.priors.params.items() if not p.free}
    rates = stiffness_rates(problem.model, draws, fixed=fixed, thetas=problem.y[: problem.n_train, 0])
    return substeps_covering(rates[np.isfinite(rates)], problem.dt)


def guess_substeps(problem: Problem, guesses) -> int:
    """Substeps the stiffest of ``guesses`` (dicts of physical values; names the model
    lacks are ignored) needs on the fitting window, at least ``problem.substeps``, at most
    :data:`MAX_SUBSTEPS`: for a problem refitted from a known fit, e.g. discovery's nested
    fallback from the current model's MAP, which would otherwise climb to them from one
    substep, a Newton polish at each doubling.  A guess whose viscous decay the solver holds
    at ``problem.substeps`` or at :data:`EDGE_SUBSTEPS` (:func:`decay_held`; a fit pinned at
    the limit is held there, :func:`map_need`) gets that count."""
    names = problem.model.start_values()

    def need(guess):
        values = {k: float(v) for k, v in guess.items() if k in names}
        full = required_substeps(problem, values)
        counts = sorted({problem.substeps, EDGE_SUBSTEPS})
        return next((n for n in counts if n < full and decay_held(problem, values, n)), full)

    return min(max([problem.substeps, *map(need, guesses)]), MAX_SUBSTEPS)


def retry_substeps(problem: Problem, guesses) -> int:
    """Substeps for another try when no MAP start simulated: the stiffness of the guesses
    (a fit of a nearby model, e.g. on a shorter window, may need more than the model's
    start values), at least twice the current number, at most :data:`MAX_SUBSTEPS`."""
    return min(max(2 * problem.substeps, guess_substeps(problem, guesses)), MAX_SUBSTEPS)


def cover_substeps(problem: Problem, density: LogDensity, found: tuple, newton_steps: int, seed: int = 0):
    """Raise ``problem``'s substeps until a MAP and its Laplace draws are covered.

    Steps 3 and 4 of :mod:`heli_uq.inference.start`: while the MAP needs more substeps than
    the problem has (:func:`map_need`; a fit pinned at the solver's limit is held at
    :data:`EDGE_SUBSTEPS`), the problem is rebuilt with them and the MAP polished again;
    then the Laplace covariance is computed and, unless the fit is pinned, the stiffness of
    :data:`TAIL_DRAWS` of its draws checked (:func:`tail_substeps`), with one more raise,
    polish and covariance if they need more.

    Parameters
    ----------
    problem, density
        The problem the MAP was found on and its log density.
    found : tuple
        ``(x_map, value, grad_max, decrement)``: the MAP (d,) in the sampler's
        unconstrained coordinates, ``-log p`` [nats], ``max |grad|`` and Newton decrement.
    newton_steps : int
        Newton steps of each polish after a raise (at least 1).
    seed : int
        Seed of the log density and of the tail draws.

    Returns
    -------
    tuple
        ``(problem, density, found, covariance, edge)``: the problem on its final substeps,
        its log density, the polished ``found``, the Laplace covariance (d, d) and the MAP's
        viscous decay pinned at the solver's limit (:func:`map_edge`) or None.
    """
    x_map = found[0]
    edge = None
    for _ in range(MAX_SUBSTEPS):
        need, edge = map_need(problem, map_values(problem, density, x_map), edge)
        if need <= problem.substeps:
            break
        problem, density, found = _polished_at(problem, need, x_map, newton_steps, seed)
        x_map = found[0]
    _, cov = laplace(density, x_map)
    tail = problem.substeps if edge else tail_substeps(problem, density, x_map, cov, seed)  # pinned: held
    need = capped_substeps(tail, "the Laplace approximation")
    if need > problem.substeps:  # the posterior's spread reaches stiffer models than its mode
        logging.getLogger(__name__).info(f"solver substeps {problem.substeps} -> {need}: the stiffest "
                                         f"of {TAIL_DRAWS} Laplace draws needs them")  # fmt: skip
        problem, density, found = _polished_at(problem, need, x_map, newton_steps, seed)
        x_map = found[0]
        _, cov = laplace(density, x_map)
    edge = map_edge(problem, map_values(problem, density, x_map)) or edge
    return problem, density, tuple(found), cov, edge


def _polished_at(problem: Problem, substeps: int, x_map, newton_steps: int, seed: int):
    """``(problem, density, found)``: ``problem`` rebuilt on ``substeps``, its log density,
    and the MAP ``x_map`` polished on it (at least one Newton step)."""
    problem = problem.with_substeps(substeps)
    density = log_density_setup(problem, seed=seed)
    return problem, density, tuple(newton_polish(density, x_map, max(newton_steps, 1))[:4])


def map_values(problem: Problem, density: LogDensity, x) -> dict:
    """The physical parameter values ``{name: float}`` at the unconstrained point ``x`` (d,)."""
    sites = density.unravel(jnp.asarray(x))
    coords = problem.coords
    z = sites["z"]
    if coords.marginal_scale:  # all coordinates, log_J_pitch included
        z = coords.marginal_log_prior(z, sites["scale_noise"])[1]
    return {k: float(v) for k, v in coords.to_physical(z).items()}
