"""The Laplace approximation as a sampler: independent Gaussian draws at the MAP, checked
by Pareto-smoothed importance sampling.

The fast alternative to NUTS for the hybrid model (a network's posterior costs NUTS deep
trees): draws ``x ~ N(x_map, H^-1)`` in numpyro's unconstrained coordinates (so skewed in
physical units), with ``H`` the Hessian of ``-log p`` at the MAP
(:func:`heli_uq.inference.prepare_start`).  They go through the same InferenceData,
diagnostics and predictive bands as NUTS draws.

How far to trust them: the importance log-weights ``log p(x) - log q(x)`` of the draws
(``q`` the Gaussian) give Pareto ``k`` (:func:`arviz.psislw`, Vehtari et al. 2024):
below :data:`PARETO_K_MAX` the Gaussian is close enough to the posterior for its
expectations; above it the run's health check fails.  Each draw costs one log-density
evaluation (one solve) for this check.  The "chains" are independent batches of draws,
so R-hat and ESS only check the bookkeeping.

:func:`importance_resample` uses the same weights to correct the draws: it resamples them
in proportion to their Pareto-smoothed weights (systematic resampling), so a Laplace
approximation that is too wide in some direction (draws that fit the data far worse than
any posterior draw would) cannot widen a predictive band.  The discovery scores its
candidates on such resampled draws.

Layer 5 (inference).
"""

from __future__ import annotations

import time

import arviz as az
import numpy as np

from heli_uq.errors import ParameterError
from heli_uq.inference.density import constrain_draws
from heli_uq.inference.sampler_run import SamplerRun
from heli_uq.inference.start import Start, prepare_start
from heli_uq.probability.problem import Problem

__all__ = ["run_laplace", "importance_resample", "resampled_draws", "psis_weights", "PARETO_K_MAX"]

#: Largest Pareto k at which the Laplace draws are trusted (Vehtari et al. 2024).
PARETO_K_MAX = 0.7


def _log_weights(start: Start, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(log p(x) - log q(x), -log p(x))`` (up to constants) of draws ``x`` (n, d).

    One draw at a time through the density's compiled potential, which the MAP has already
    compiled: a batched (``vmap``) potential would be one more program to compile (3-4 s),
    and on the rig's 131 s record it costs more per draw, not less (4.3 against 2.5 ms, 64
    draws at once)."""
    potential = start.density.potential_jit
    pot = np.array([float(potential(xi)) for xi in np.asarray(x)])
    diff = x - start.x_map[None, :]
    prec = np.linalg.pinv(start.covariance, hermitian=True)
    log_q = -0.5 * np.einsum("ni,ij,nj->n", diff, prec, diff)
    return np.where(np.isfinite(pot), -pot - log_q, -np.inf), pot


def psis_weights(log_w: np.ndarray) -> tuple[np.ndarray, float]:
    """Normalised Pareto-smoothed importance weights (n,) of log-weights ``log_w`` (n,)
    (``-inf`` where a draw's log density is not finite: weight 0) and their Pareto ``k``
    (:func:`arviz.psislw`)."""
    log_w = np.asarray(log_w, dtype=float)
    finite = np.isfinite(log_w)
    if not finite.any():
        return np.full(log_w.shape, np.nan), float("inf")
    # Log-weights spread over hundreds of nats (a Laplace approximation far from the
    # posterior) give a tail fit with k ~ 100-200, whose inverse CDF overflows to inf inside
    # arviz; arviz then caps the smoothed tail at the largest raw weight, so the result is
    # right and only numpy's warning (an error under ``-W error``) is spurious.
    with np.errstate(over="ignore"):
        smoothed, k = az.psislw(np.where(finite, log_w, np.min(log_w[finite]) - 50.0))
    w = np.where(finite, np.exp(smoothed - np.max(smoothed[finite])), 0.0)
    return w / w.sum(), float(k)


def importance_resample(start: Start, n: int, seed: int = 0) -> tuple[dict, dict]:
    """``n`` Laplace draws at the MAP, resampled by their importance weights toward the
    posterior (module docstring): :func:`resampled_draws`, constrained.

    Returns
    -------
    sites : dict
        ``{name: array (n, ...)}``, constrained sites as :meth:`Start.laplace_draws`; draws
        of large weight repeated, draws of negligible weight left out.
    info : dict
        As :func:`resampled_draws`.

    Raises
    ------
    ParameterError
        When no draw has a finite log density.
    """
    x, info = resampled_draws(start, n, seed)
    return constrain_draws(start.density, x), info


def resampled_draws(start: Start, n: int, seed: int = 0) -> tuple[np.ndarray, dict]:
    """``n`` draws of ``N(start.x_map, start.covariance)`` resampled in proportion to their
    Pareto-smoothed importance weights toward ``exp(-start.density.potential)``.

    Returns
    -------
    x : ndarray, shape (n, d)
        The resampled draws in the sampler's unconstrained coordinates (systematic
        resampling: draw ``i`` kept ``floor`` or ``ceil`` of ``n w_i`` times).
    info : dict
        ``pareto_k`` (above :data:`PARETO_K_MAX`: the Gaussian was far from the posterior
        and the resampled draws are few distinct ones near its mode, too narrow), ``ess``
        (the weights' effective sample size, ``1 / sum w^2``), ``distinct`` (distinct draws
        kept) and ``failed_draws`` (draws whose solve failed).

    Raises
    ------
    ParameterError
        When no draw has a finite log density.
    """
    rng = np.random.default_rng(seed)
    x = start.gaussian_draws(n, rng)
    log_w, _ = _log_weights(start, x)
    w, k = psis_weights(log_w)
    if not np.all(np.isfinite(w)):
        raise ParameterError(f"Laplace draws: none of {n} has a finite log density")
    idx = np.minimum(np.searchsorted(np.cumsum(w), (rng.uniform() + np.arange(n)) / n), n - 1)
    info = {"pareto_k": k, "ess": float(1.0 / np.sum(w**2)), "distinct": int(np.unique(idx).size),
            "failed_draws": int(np.sum(~np.isfinite(log_w)))}  # fmt: skip
    return x[idx], info


def run_laplace(problem: Problem, out_dir=None, *, chains: int = 4, draws: int = 1000, seed: int = 0,
                start: Start | None = None, progress: bool = False):  # fmt: skip
    """``chains x draws`` independent draws of the Laplace approximation (module docstring).

    Returns
    -------
    SamplerRun
        ``info`` holds ``pareto_k`` and, when it exceeds :data:`PARETO_K_MAX`, a warning
        in ``warnings`` (failed by the health check).
    """
    t0 = time.perf_counter()
    start = prepare_start(problem, seed=seed) if start is None else start
    rng = np.random.default_rng(seed)
    x = start.gaussian_draws(chains * draws, rng)
    log_w, potential = _log_weights(start, x)
    finite = np.isfinite(log_w)
    _, k = psis_weights(log_w)
    flat = constrain_draws(start.density, x)
    samples = {name: v.reshape((chains, draws) + v.shape[1:]) for name, v in flat.items()}
    info = dict(start.info(), sampler="laplace", chains=chains, draws=draws, seed=seed, pareto_k=k,
                failed_draws=int((~finite).sum()), wall_seconds=time.perf_counter() - t0)  # fmt: skip
    if not k <= PARETO_K_MAX:
        info["warnings"] = [f"Pareto k {k:.2f} > {PARETO_K_MAX}: the Laplace approximation is far "
                            "from the posterior (use NUTS)"]  # fmt: skip
    stats = {"potential_energy": potential.reshape(chains, draws)}
    return SamplerRun(samples=samples, stats=stats, info=info, problem=start.problem)
