"""The shared start of every sampler: multi-start least squares, the MAP, the Laplace
covariance, and the number of solver substeps the fitted parameters need.

1. **Least squares** (:func:`heli_uq.inference.multistart.map_starts`):
   Levenberg-Marquardt on the sampling coordinates and the initial state.  Started from
   :func:`~heli_uq.inference.multistart.start_parameters`, and from one more start where
   a term's start grid finds a better basin
   (:func:`heli_uq.inference.least_squares.grid_start`).  If no start
   simulates the record after its fit (a guess fitted on another window may be stiffer
   than the model's start values), they are fitted again with more substeps.
2. **MAP** on the full log posterior (:func:`heli_uq.inference.map.find_map`): damped
   Newton steps from the least-squares fits (optionally after L-BFGS).
3. **Substeps** (steps 3 and 4: :func:`heli_uq.inference.substeps.cover_substeps`).  A
   stiff effect (sharp friction) needs more RK4 substeps the larger its fitted level; if
   the MAP needs more than the problem has, the problem is rebuilt with them and the MAP
   polished again, as often as the polished MAP needs more, up to
   :data:`~heli_uq.simulation.stiffness.MAX_SUBSTEPS`.  A model that imitates a missing
   friction with damping stiffens at every raise (a pitch-friction record's base model:
   1 -> 2 -> 4 -> 8 -> 16 substeps).  Such a MAP sits at RK4's limit at every count
   (``r h`` = 2.78 at 16), so a fit found pinned there is raised to
   :data:`~heli_uq.inference.substeps.EDGE_SUBSTEPS` only and held (``solver_edge`` and
   the cap's warning say so; since 2026-12-07, before that it climbed to 16).
4. **Laplace covariance** at the MAP; then the substeps are checked once more against the
   stiffness of :data:`~heli_uq.inference.substeps.TAIL_DRAWS` Laplace draws
   (:func:`heli_uq.simulation.stiffness.substeps_covering`), so that the posterior's draws,
   not only its mode, are simulated accurately; if they need more, the MAP is polished and
   the covariance computed again.  (Until 2026-11-28 the MAP's stiffness times 2 decided:
   on a pitch friction record that gave 6 substeps where the stiffest of 1992 NUTS draws
   needs 4, and a posterior wider in the stiffness than a factor 2 would have been simulated
   wrongly in its tail, with no sign.)

With a neural term (the hybrid model) the Newton polish is capped at
:data:`NETWORK_NEWTON_STEPS` on the best least-squares start and then moved off any saddle
(:func:`~heli_uq.inference.map.leave_saddles`): the Laplace covariance whitens NUTS around
a local optimum, not necessarily the global one.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from heli_uq.errors import ParameterError
from heli_uq.inference.density import LogDensity, constrain_draws, init_sites, log_density_setup
from heli_uq.inference.gaussian import gaussian_draws
from heli_uq.inference.map import NEWTON_STEPS, find_map, leave_saddles
from heli_uq.inference.multistart import map_starts, startable
from heli_uq.inference.substeps import cover_substeps, retry_substeps
from heli_uq.model.tables import X0_NAMES
from heli_uq.model.terms.neural_torque import NeuralTorque
from heli_uq.probability.problem import Problem
from heli_uq.simulation.stiffness import MAX_SUBSTEPS

__all__ = ["Start", "map_parameters", "prepare_start", "initial_draws", "whitening",
           "NETWORK_NEWTON_STEPS", "MAP_DECREMENT_MAX", "NETWORK_MAP_DECREMENT_MAX", "PoorBasin"]

#: Newton steps of the MAP of a model with a neural term.  Its posterior is not convex (the
#: weights' symmetries, flat directions where the prior dominates), so the decrement falls
#: slowly and rarely reaches NEWTON_TOL; each step costs 2 d gradients (d ~ 30-150), so
#: the polish is capped.  On a 60 s synthetic record (d = 27) the least-squares start was
#: 10,000 nats below the optimum: 10 steps closed half of that, 30 steps all but a
#: decrement of 0.24 nats (16 s); L-BFGS first gained nothing.
NETWORK_NEWTON_STEPS = 60
#: Largest Newton decrement g^T H^-1 g [nats] of a converged MAP: its square root is the
#: distance to the optimum in posterior sd (0.03 sd).
MAP_DECREMENT_MAX = 1e-3
#: The same for a model with a neural term, whose capped polish stops short of the optimum
#: (within ~1 posterior sd): its MAP only starts NUTS, which adapts its mass matrix.
NETWORK_MAP_DECREMENT_MAX = 1.0
#: Rounds of redrawing initial sampler positions whose log density is not finite.
MAX_INIT_ROUNDS = 100


class PoorBasin(ParameterError):
    """The MAP search ended above the caller's ``abandon_above`` (:func:`prepare_start`)."""


def map_parameters(density: LogDensity, x_map) -> tuple[dict, np.ndarray]:
    """The point ``x_map`` (d,) of the sampler's unconstrained coordinates as ``(params,
    x0)``: every model parameter [SI] (fixed ones at their fixed values) and the initial
    state (4,) [rad, rad, rad/s, rad/s]."""
    best = {k: np.asarray(v[0]) for k, v in constrain_draws(density, np.asarray(x_map)[None]).items()}
    params = {n: float(best[n]) if n in best else float(p.a)
              for n, p in density.problem.priors.params.items()}  # fmt: skip
    return params, np.array([float(best[n]) for n in X0_NAMES])


@dataclasses.dataclass(frozen=True, eq=False)
class Start:
    """A MAP start: the problem (with its final substeps), its log density, the MAP point,
    its Laplace covariance and how the MAP converged."""

    problem: Problem
    density: LogDensity
    x_map: np.ndarray
    map_value: float
    covariance: np.ndarray
    map_seconds: float
    #: Convergence of the MAP: ``max |grad|`` and Newton decrement at ``x_map``.
    map_grad_max: float = float("nan")
    map_decrement: float = float("nan")
    #: Largest decrement [nats] at which this start counts as converged (the health check).
    map_decrement_max: float = MAP_DECREMENT_MAX
    #: The MAP's viscous decay pinned at the solver's limit (``substeps.map_edge``), or None.
    solver_edge: dict | None = None

    def log_evidence(self) -> float:
        """The Laplace approximation of the log marginal likelihood of the data [nats]:
        ``-map_value + 0.5 log det(2 pi covariance)``.  ``map_value`` is ``-log p`` in the
        sampler's unconstrained coordinates, their Jacobian included, so the value does
        not depend on the units or coordinates of the parameters (a log posterior density
        at the MAP does)."""
        _, logdet = np.linalg.slogdet(2.0 * np.pi * np.asarray(self.covariance))
        return -float(self.map_value) + 0.5 * float(logdet)

    def laplace_draws(self, n: int, seed: int = 0) -> dict:
        """``n`` draws of the Laplace approximation at the MAP (Gaussian in the sampler's
        unconstrained coordinates, so skewed in physical units), as constrained sites:
        ``{name: array (n, ...)}`` (parameters, initial state, residual scales)."""
        return constrain_draws(self.density, self.gaussian_draws(n, np.random.default_rng(seed)))

    def gaussian_draws(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """``n`` draws (n, d) of the Laplace approximation ``N(x_map, covariance)`` in the
        sampler's unconstrained coordinates."""
        return gaussian_draws(self.x_map, self.covariance, n, rng)

    def map_point(self) -> tuple[dict, np.ndarray]:
        """The MAP as ``(params, x0)``: every model parameter [SI] (fixed ones at their
        fixed values) and the initial state (4,) [rad, rad, rad/s, rad/s]."""
        return map_parameters(self.density, self.x_map)

    def map_guess(self) -> dict:
        """The MAP as one guess dict for a refit (:func:`prepare_start`'s ``guesses``): every
        model parameter [SI] and the initial state by name (``theta0`` ... [rad, rad/s])."""
        params, x0 = self.map_point()
        return {**params, **dict(zip(X0_NAMES, map(float, x0)))}

    def info(self) -> dict:
        """JSON-ready facts of the start (without the arrays)."""
        return {"map_value": float(self.map_value), "map_seconds": float(self.map_seconds),
                "map_grad_max": float(self.map_grad_max),
                "map_decrement": float(self.map_decrement),
                "map_decrement_max": float(self.map_decrement_max),
                "substeps": int(self.problem.substeps), **({"solver_edge": self.solver_edge}
                                                            if self.solver_edge else {})}  # fmt: skip


def initial_draws(batched_log_density, n: int, dim: int, rng: np.random.Generator, *,
                  scale: float = 1.0, on_failure: str = "map") -> np.ndarray:  # fmt: skip
    """``n`` draws ``w ~ N(0, scale^2 I)`` in whitened Laplace coordinates at which the log
    density is finite (``batched_log_density``: ``w (n, dim) -> (n,)``, e.g. the sampler's
    own target).

    Failing draws are redrawn up to :data:`MAX_INIT_ROUNDS` times; then ``on_failure``
    ``"map"`` sets them to 0 (the MAP), ``"raise"`` raises a :class:`ParameterError`.
    """
    w = scale * rng.standard_normal((n, dim))
    for _ in range(MAX_INIT_ROUNDS):
        bad = ~np.isfinite(np.asarray(batched_log_density(w)))
        if not bad.any():
            return w
        w[bad] = scale * rng.standard_normal((int(bad.sum()), dim))
    if on_failure == "raise":
        raise ParameterError(f"{int(bad.sum())} of {n} initial points still have a non-finite log "
                             f"density after {MAX_INIT_ROUNDS} redraws around the MAP (the model "
                             "diverges near the MAP)")  # fmt: skip
    w[bad] = 0.0
    return w


def whitening(start_info: dict) -> tuple[np.ndarray, np.ndarray]:
    """``(x_map, L)`` with ``L L^T`` the Laplace covariance: ``x = x_map + L w``."""
    cov = np.asarray(start_info["covariance"], dtype=float)
    return np.asarray(start_info["x_map"], dtype=float), np.linalg.cholesky(0.5 * (cov + cov.T))


def _density(problem: Problem, seed: int, guesses) -> LogDensity:
    """The log density, set up at the model's start values or, where its simulation from
    them fails, at the first guess that simulates (the record's first angles, at rest)."""
    try:
        return log_density_setup(problem, seed=seed)
    except ParameterError:
        x0 = np.concatenate([np.asarray(problem.y[0], dtype=float), np.zeros(2)])
        for guess in guesses:
            values = init_sites(problem, {**problem.model.start_values(), **startable(problem, guess)}, x0)
            try:
                return log_density_setup(problem, init_values=values, seed=seed)
            except ParameterError:
                continue
        raise


def prepare_start(problem: Problem, *, n_starts: int = 4, seed: int = 0,
                  map_maxiter: int = 0, guesses=(), newton_steps: int | None = None,
                  polish_best: int | None = None, abandon_above: float | None = None,
                  grid: bool = True, from_fit: bool = False, log=None) -> Start:  # fmt: skip
    """Multi-start MAP, substeps check and Laplace covariance (module docstring).

    ``guesses``: parameter dicts tried first (see
    :func:`~heli_uq.inference.multistart.map_starts`); ``n_starts`` counts
    them (with ``n_starts <= len(guesses)`` only the first ``n_starts`` guesses are tried,
    e.g. to refit a model from a nearby one).
    ``newton_steps``, ``polish_best``: see :func:`~heli_uq.inference.map.find_map` (fewer
    steps and one polished start trade MAP accuracy, ~0.01 nats, for speed, e.g. when many
    candidate models are compared).  Default: :data:`NEWTON_STEPS`; for a model with a
    neural term :data:`NETWORK_NEWTON_STEPS` and ``polish_best=1`` (module docstring).

    ``map_maxiter``: L-BFGS steps per start before the Newton polish.  The default 0 goes
    straight from the least-squares fits to Newton: the same optimum (to 1e-9 nats on the
    rig and the test records) in about half the time (L-BFGS's compilation costs more).
    ``abandon_above``: a ``-log p`` [nats] above which the MAP search is not finished: if
    the best start's polished value ends above it, :class:`PoorBasin` is raised before the
    substeps are raised and the Laplace covariance is computed (a caller with a better fit
    in hand, e.g. a nested model's, saves that work; in discovery it was 60-90 % of a
    stiff candidate's fit).
    ``grid``: add the start grid's start; ``from_fit``: the guesses are fits of a nearby
    model (both: see :func:`~heli_uq.inference.multistart.map_starts`).  ``log``: called
    with a line per least-squares start.

    If no start simulates the record after its least-squares fit (each fit moved into a
    model too stiff for the problem's substeps), the starts are fitted again with more
    substeps (:func:`~heli_uq.inference.substeps.retry_substeps`), up to
    :data:`~heli_uq.simulation.stiffness.MAX_SUBSTEPS`.

    Raises
    ------
    ParameterError
        If no start gives a finite log density, or no start simulates the record after its
        least-squares fit, even at ``MAX_SUBSTEPS``.
    PoorBasin
        If the MAP ends above ``abandon_above``.
    """
    t0 = time.perf_counter()
    network = any(isinstance(t, NeuralTorque) for t in problem.model.torques)
    if newton_steps is None:
        newton_steps = NETWORK_NEWTON_STEPS if network else NEWTON_STEPS
        polish_best = 1 if network and polish_best is None else polish_best
    density = _density(problem, seed, guesses)
    starts = map_starts(problem, density, max(n_starts, 1), seed, guesses, grid=grid,
                        from_fit=from_fit, log=log)
    while not starts and problem.substeps < MAX_SUBSTEPS:  # every fit left a model too stiff
        problem = problem.with_substeps(retry_substeps(problem, guesses))
        if log is not None:
            log(f"no MAP start simulates the record: again at {problem.substeps} solver substeps")
        density = _density(problem, seed, guesses)
        starts = map_starts(problem, density, max(n_starts, 1), seed, guesses, grid=grid,
                        from_fit=from_fit, log=log)
    if not starts:
        raise ParameterError(
            "no MAP start simulates the record: the least-squares fit of every start gave a "
            f"model whose simulation diverges at {problem.substeps} solver substep(s) per "
            "sample (try other starting values, a shorter window or tighter priors)"
        )
    result = find_map(density, starts, maxiter=map_maxiter, newton_steps=newton_steps,
                      polish_best=polish_best)  # fmt: skip
    if not np.isfinite(result.value):
        raise ParameterError(
            "no MAP start gave a finite log density: the model diverges from every start "
            "(check the data window and the priors)"
        )
    x_map, value, grad_max, decrement = result.x, result.value, result.grad_max, result.newton_decrement
    if abandon_above is not None and value > abandon_above:
        raise PoorBasin(f"the MAP ends at -log p = {value:.6g}, above the limit {abandon_above:.6g}")
    if network:  # a capped polish of a non-convex posterior may stop at a saddle
        moved = leave_saddles(density, x_map)
        if moved[4] > 0:
            x_map, value, grad_max, decrement = moved[:4]
    problem, density, (x_map, value, grad_max, decrement), cov, edge = cover_substeps(
        problem, density, (x_map, value, grad_max, decrement), newton_steps, seed)
    limit = NETWORK_MAP_DECREMENT_MAX if network else MAP_DECREMENT_MAX
    return Start(problem, density, np.asarray(x_map), float(value), cov, time.perf_counter() - t0,
                 float(grad_max), float(decrement), limit, edge)

