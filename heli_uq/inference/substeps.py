"""The RK4 substeps per sample a fit needs: at a parameter point (its stiffness), over a
set of starting guesses, and over the Laplace approximation's tail draws.

A stiff effect (sharp friction, a large damping) needs more substeps the larger its level;
:func:`heli_uq.inference.start.prepare_start` raises a problem's substeps with these.
"""

from __future__ import annotations

import numpy as np

from heli_uq.inference.density import LogDensity, constrain_draws
from heli_uq.inference.gaussian import gaussian_draws
from heli_uq.probability.problem import Problem
from heli_uq.simulation.stiffness import (
    MAX_SUBSTEPS,
    SMOOTHER_FRICTION,
    capped_substeps,
    damping_edge,
    default_substeps,
    edge_text,
    stiffness_rates,
    substeps_covering,
)

__all__ = ["TAIL_DRAWS", "required_substeps", "map_need", "map_edge", "tail_substeps",
           "guess_substeps", "retry_substeps"]  # fmt: skip

#: Laplace draws (seeded) whose stiffness the substeps must cover (their maximum is about
#: the 99.8 % quantile of the rate).  The output stage checks every posterior draw again
#: (:func:`heli_uq.simulation.stiffness.stiffness_check`).
TAIL_DRAWS = 256


def required_substeps(problem: Problem, params: dict) -> int:
    """Substeps the model needs at ``params`` on the fitting window."""
    return default_substeps(problem.model, params, problem.dt, thetas=problem.y[: problem.n_train, 0])


def map_edge(problem: Problem, params: dict) -> dict | None:
    """The viscous decay of a fit at ``params`` pinned at RK4's stability limit on
    ``problem``'s substeps (:func:`heli_uq.simulation.stiffness.damping_edge`), or None."""
    return damping_edge(problem.model, params, problem.dt, problem.substeps,
                        thetas=problem.y[: problem.n_train, 0])  # fmt: skip


def map_need(problem: Problem, params: dict) -> int:
    """The substeps a MAP at ``params`` needs (:func:`required_substeps`), capped at
    :data:`MAX_SUBSTEPS`; the warning at the cap says so when the fit's damping sits at the
    solver's limit (:func:`map_edge`), and suggests a smoother friction otherwise.  Below
    the cap the need is capped silently: the MAP is raised to the cap and checked again, so
    the warning is given once, on the MAP that stays."""
    need = required_substeps(problem, params)
    if need <= MAX_SUBSTEPS or problem.substeps < MAX_SUBSTEPS:
        return min(need, MAX_SUBSTEPS)
    edge = map_edge(problem, params)
    return capped_substeps(need, "the MAP", edge_text(edge) if edge else SMOOTHER_FRICTION)


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
    substep, a Newton polish at each doubling."""
    names = problem.model.start_values()
    need = [required_substeps(problem, {k: float(v) for k, v in g.items() if k in names})
            for g in guesses]  # fmt: skip
    return min(max([problem.substeps, *need]), MAX_SUBSTEPS)


def retry_substeps(problem: Problem, guesses) -> int:
    """Substeps for another try when no MAP start simulated: the stiffness of the guesses
    (a fit of a nearby model, e.g. on a shorter window, may need more than the model's
    start values), at least twice the current number, at most :data:`MAX_SUBSTEPS`."""
    return min(max(2 * problem.substeps, guess_substeps(problem, guesses)), MAX_SUBSTEPS)
