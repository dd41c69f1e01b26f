"""Where the MAP search starts: parameter guesses, and each guess fitted by least squares.

Step 1 of :mod:`heli_uq.inference.start`.  :func:`map_starts` fits every guess (a fit of a
nearby model, the model's start values, its defaults, log-normal perturbations and a
term's start grid) by Levenberg-Marquardt twice, the second time with the residual scales
of the first, and returns the fitted points in the sampler's unconstrained coordinates;
:func:`start_parameters` makes the guesses (shared with the identifiability fit).
"""

from __future__ import annotations

import time

import jax
import jax.numpy as jnp
import numpy as np

from heli_uq.inference.density import LogDensity, init_sites
from heli_uq.inference.error_start import error_start, residual_rms
from heli_uq.inference.least_squares import LSQ_SIGMA, grid_start, least_squares_fit, x0_guess
from heli_uq.probability.problem import Problem

__all__ = ["start_parameters", "startable", "map_starts", "RESCALE_RTOL"]

#: Relative change of the residual scales below which a least-squares start weighted by
#: its guess's own scales is not fitted again (:func:`map_starts` with ``from_fit``).
RESCALE_RTOL = 0.1


def start_parameters(free, base: dict, n: int, seed: int = 0, *, alternative: dict | None = None,
                     linear=()) -> list[dict]:  # fmt: skip
    """Parameter guesses of a multi-start fit (shared by the MAP and the identifiability fit).

    ``base``; then ``base`` with ``alternative`` values for the ``free`` names (e.g. the
    paper's Table 2 where the base is Table 1); then ``n - 2`` log-normal (sd 0.3)
    perturbations of ``base``'s free parameters other than those in ``linear`` (which
    may be 0 or negative).  Returns ``n`` dicts.
    """
    rng = np.random.default_rng(seed)
    out = [dict(base)]
    if alternative is not None:
        out.append({p: (alternative.get(p, v) if p in free else v) for p, v in base.items()})
    while len(out) < n:
        out.append({p: v * (float(np.exp(rng.normal(0, 0.3))) if p in free and p not in linear
                            else 1.0) for p, v in base.items()})  # fmt: skip
    return out[:n]


def _alternative_values(problem: Problem) -> dict:
    """Each free parameter's default where it lies inside its prior's open support (Table 2
    for the mechanics), else its start value."""
    out = {}
    for par in problem.model.parameters():
        prior = problem.priors.params[par.name]
        lo, hi = prior.support
        out[par.name] = par.default if lo < par.default < hi else par.start_value()
    return out


def startable(problem: Problem, guess: dict) -> dict:
    """The entries of ``guess`` (physical values by name) a fit can start from: names of the
    model's parameters, each free one strictly inside its support.  A value on a bound (an
    effect's "no effect" level 0 of a friction or an amplitude, whose sampling coordinate is
    its logarithm) is left out, so the model's start value takes its place: kept, it made
    the start's least-squares cost infinite and the start was dropped (a warm start from a
    fit of a smaller model with the new effect at its default, 2026-11-30)."""
    pars = {p.name: p for p in problem.model.parameters()}
    free = set(problem.coords.free)
    return {k: float(v) for k, v in guess.items()
            if k in pars and (k not in free or pars[k].inside(float(v)))}  # fmt: skip


def map_starts(problem: Problem, density: LogDensity, n: int, seed: int = 0, guesses=(), *,
               grid: bool = True, from_fit: bool = False, log=None) -> list:  # fmt: skip
    """Starting points (flat vectors) of the MAP, each refined by :func:`least_squares_fit`.

    Each guess is fitted twice, the second time with the residual scales of the first fit
    (so the least-squares weighting of pitch against yaw is the MAP's, and the Newton polish
    starts next to the optimum).  With ``from_fit`` the guesses are fits of a nearby model
    (e.g. discovery's nested fallback, the current model with a new effect switched off):
    each is fitted from its own initial state (:func:`x0_guess`) with the residual scales
    it leaves, and fitted again only if its fit moves those scales by more than
    :data:`RESCALE_RTOL` (at 11 substeps the second pass was half of such a refit).
    Guesses: ``guesses`` (dicts of physical values, e.g. a fit of a smaller model; missing
    names, and values on a bound of a free parameter's support (:func:`startable`), take
    the model's start values), then the model's start values (Table 1 for the
    mechanics), its defaults where valid (Table 2) and ``n - 2`` perturbations; for a
    model whose terms declare a start grid, one more from :func:`grid_start` (unless
    ``grid`` is False: a refit from a given start, e.g. discovery's nested fallback, wants
    that start's basin, not another).  After the
    least-squares stage the residual scale starts at the residual RMS and the AR(1)
    correlation time at the one of the residuals' lag-1 autocorrelation, so the MAP search
    starts close to its optimum.
    ``log``, if given, is called with one line per finished start.
    """
    coords = problem.coords
    fit = least_squares_fit(problem)
    sim = jax.jit(lambda z, x0: problem.solve(coords.to_physical(z), x0, problem.n_train).ys)
    fixed = {k: p.a for k, p in problem.priors.params.items() if not p.free}
    # each guess is moved along the common scale to meet a fixed inertia-scaled value
    on_scale = problem.model.on_the_scale_of
    start = problem.model.start_values()
    base = on_scale(start, fixed)
    alternative = on_scale(_alternative_values(problem), fixed)
    linear = [p.name for p in problem.model.parameters() if p.interval[0] < 0]  # may be <= 0
    out = []
    t0 = time.perf_counter()
    warm = [on_scale({**start, **startable(problem, g)}, fixed) for g in guesses][:n]
    starts = warm + start_parameters(coords.free, base, n, seed, alternative=alternative,
                                     linear=linear)[: max(n - len(warm), 0)]  # fmt: skip
    screened = grid_start(problem, starts[0], log=log) if grid else None
    starts += [screened] if screened is not None else []
    y = problem.y[: problem.n_train]
    for k, params in enumerate(starts):
        refit = from_fit and k < len(warm)
        z0 = jnp.asarray(coords.from_physical(params))
        x_start = x0_guess(problem, guesses[k] if refit else None)
        weights = LSQ_SIGMA
        if refit:  # weighted by the residual scales the fit leaves
            left = np.asarray(sim(z0, jnp.asarray(x_start)))[:, :2] - y
            weights = residual_rms(left) if np.all(np.isfinite(left)) else LSQ_SIGMA
        z, x0, cost = (np.asarray(a) for a in fit(z0, x_start, weights))
        states = np.asarray(sim(jnp.asarray(z), jnp.asarray(x0)))
        resid = states[:, :2] - y
        usable = bool(np.all(np.isfinite(resid)))
        if log is not None:
            log(f"MAP start {k + 1}/{len(starts)}: least-squares cost {float(cost):.6g} "
                f"({time.perf_counter() - t0:.0f} s)"
                + ("" if usable else "; the model does not simulate from it: skipped"))  # fmt: skip
        if not usable:
            continue
        # again with the residual scales of this fit (the MAP's weighting of theta vs psi)
        sigma = residual_rms(resid)
        own = refit and np.allclose(sigma, weights, rtol=RESCALE_RTOL, atol=0)
        if not own:  # (a fit's guess weighted by its own scales already is not fitted again)
            z2, x2, _ = (np.asarray(a) for a in fit(z, x0, sigma))
            states2 = np.asarray(sim(jnp.asarray(z2), jnp.asarray(x2)))
            if np.all(np.isfinite(states2[:, :2])):
                z, x0, states = z2, x2, states2
        sigma, tau, timing = error_start(states[:, :2] - y, states[:, 2:4], problem.dt, problem.timing)
        phys = {k: float(v) for k, v in coords.to_physical(jnp.asarray(z)).items()}
        sites = init_sites(problem, phys, x0, sigma, tau, timing)
        # numpyro's unconstrained space: log of the positive sites
        unconstrained = {k: (jnp.log(v) if k.startswith(("sigma_", "tau_", "timing_")) else v)
                         for k, v in sites.items()}  # fmt: skip
        out.append(density.ravel(unconstrained))
    return out

