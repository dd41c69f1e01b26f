"""One model fitted and scored: the task the discovery runs per candidate (on Dask workers).

:func:`fit_and_score` fits a model (the base plus effects) on the fitting window: a
multi-start MAP (:func:`heli_uq.inference.prepare_start`) started first from the warm
guesses (the current model's MAP with each new effect parameter at its implied value from
the sparse regression, and at its probe value), with iid errors.  A candidate nests the
current model, so its MAP should be at least as good; if its ``-log p`` ends more than
:data:`NESTED_SLACK_NATS` above the current model's (a start in a poor basin), it is refitted
from the current MAP with the new effect switched off (:func:`off_start`), which starts
from the current model's fit and can only improve on it, and the better MAP is kept (a
start :data:`ABANDON_NATS` above is given up before its costly finish).  The fallback is
built at the solver substeps the current fit needs and without a start grid's extra start
(:func:`heli_uq.inference.substeps.guess_substeps`), and its least squares start from
that fit's initial state, weighted by its residual scales, in one pass
(``prepare_start(..., from_fit=True)``): it restarts that fit, so it need not climb to
the substeps from one, nor find the scales again (on a stiff pitch friction record a dead
band's fallback took 133 s; at the current fit's substeps 110 s, and 60 s in one pass on
the same day, to a MAP 4 nats better).  It
then draws the Laplace approximation at the MAP, resamples the draws by their importance
weights toward the posterior (:func:`heli_uq.inference.importance_resample`), simulates
every draw once over fitting and held-out window, and returns the gap metrics of both
windows and the held-out block scores (:mod:`heli_uq.discovery.score`).

Why resample: a Laplace covariance that is too wide in one direction gives draws that fit
the fitting window far worse than any posterior draw, and their spread widens the
held-out band.  Where the current model predicts the held-out window badly, a wider band
alone raises the log predictive density, so such a candidate would win for its poor
approximation.  On the rig record (0-91 s) a pitch friction + yaw dead band pair did: its
MAP is the base model's fit (train yaw RMSE 0.278 rad), its raw Laplace draws fit the
fitting window with yaw RMSE up to 0.75 rad (median 400 nats of ``-log p`` above the MAP,
Pareto k 1.9) and scored +16654 +- 6715 nats; NUTS then found the base model's fit
again.  Where Pareto k exceeds :data:`~heli_uq.inference.laplace_sampler.PARETO_K_MAX` the
weights themselves are not trusted (with k = inf on the rig, one of 64 draws took all the
weight and its chance extrapolation scored +3679 nats), so the candidate's predictive is
the plug-in one at the MAP (parameter uncertainty left out, the residual noise kept;
``laplace.predictive`` says which).  The result is a JSON-able dict, so it can be stored
and reused when a run is repeated with the same ``--out``.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from heli_uq.data import Experiment
from heli_uq.discovery.score import MIN_BLOCKS, block_crps, block_scores, gap_metrics, input_blocks
from heli_uq.errors import ParameterError
from heli_uq.inference import constrain_draws, importance_resample, prepare_start, settle_edge
from heli_uq.inference.laplace_sampler import PARETO_K_MAX
from heli_uq.inference.start import PoorBasin
from heli_uq.inference.substeps import guess_substeps
from heli_uq.model import AXES, RIG_FIT, build_model
from heli_uq.model.prior import Prior
from heli_uq.output.inference_data import simulate_draws
from heli_uq.probability import make_problem
from heli_uq.probability.priors import PriorSet

__all__ = ["FitTask", "fit_and_score", "score_fitted", "Fitted", "fitted_predictive", "probe_values",
           "warm_starts", "off_start", "model_priors", "NESTED_SLACK_NATS", "ABANDON_NATS", "OFF_FRACTION"]

#: A nested candidate's MAP may end this far [nats of -log posterior] above the current
#: model's before it is refitted from "effect off".  The slack covers the new parameters'
#: own prior terms (in log coordinates a parameter the data do not want costs a few nats);
#: the poor basins this guards against are thousands of nats worse.
NESTED_SLACK_NATS = 25.0
#: A candidate's start whose MAP (before its substeps are raised) ends this far [nats]
#: above the current model's is abandoned for the nested fallback.  Raising the substeps
#: moves a MAP little: measured on a 131 s record (yaw friction, F_c = 0.076 N m at the
#: poor MAP, substeps 3 -> 14) by 50 nats, where that start was 39,000 nats above the
#: current model and finishing it took 117 of the candidate's 163 s.
ABANDON_NATS = 1000.0
#: "Off" of a parameter whose off value (its default) is a bound of its support, e.g.
#: ``F_c = 0`` of a log coordinate: this fraction of its probe value, close enough to off
#: that the start reproduces the current fit, inside the support so the fit can grow it.
OFF_FRACTION = 1e-3


def probe_values(model, current: dict, names) -> dict:
    """First guesses of the new parameters ``names`` of ``model`` next to a fit ``current``.

    A parameter's declared start value is meant for the model's start values (Table 1).
    The common inertia scale is not identified, so a fit may sit at any multiple of it:
    a parameter that scales with the inertias (a friction level, a torque offset) is
    identified only as a ratio to its axis inertia, and its guess follows that ratio,
    ``start * M_axis(current) / M_axis(start values)`` (``M11``, or ``M22`` at zero
    pitch).  Other parameters keep their start values.
    """
    ref = model.complete(model.start_values())
    here = model.complete({k: v for k, v in current.items() if k in model.names})
    m_ref = model.mechanics.inertia_bounds(ref, [0.0])
    m_here = model.mechanics.inertia_bounds(here, [0.0])
    out = {}
    for name in names:
        par = model.parameter(name)
        scale = 1.0
        if par.scales_with_inertia and par.axis is not None:
            i = AXES.index(par.axis)
            scale = m_here[i] / m_ref[i] if m_ref[i] > 0 and m_here[i] > 0 else 1.0
        out[name] = par.start_value() * scale
    return out


def _inside_support(model, values: dict) -> dict:
    """The finite ``values`` clipped into their parameters' supports, less those that
    land on a bound (a positive parameter implied negative keeps its probe)."""
    out = {}
    for par in model.parameters():
        if par.name in values and np.isfinite(values[par.name]):
            v = float(np.clip(values[par.name], *par.interval))
            if par.inside(v):
                out[par.name] = v
    return out


def warm_starts(current_map: dict, effects: list[str], implied: dict) -> tuple[dict, ...]:
    """MAP starts of a candidate model ``effects`` next to the current fit ``current_map``.

    1. the current MAP with the new parameters at their probe values (:func:`probe_values`);
    2. the same at the values the sparse regression implies (``implied``, clipped into
       their supports), if any differ;
    3. the shipped fit of the rig record (:data:`heli_uq.model.RIG_FIT`) for the mechanics,
       the new parameters probed next to it.  A hidden effect can pull the current model
       into a basin from which no local move reaches it: on a record with pitch Coulomb
       friction the model without it explains pitch with K_theta_theta / M11 = 0.08 (the
       truth 3.75), and friction started there ends 17,500 nats below the truth's basin,
       which this start reaches.
    """
    model = build_model(effects)
    new = [p.name for p in model.parameters() if p.name not in current_map]
    probe = {**current_map, **probe_values(model, current_map, new)}
    seeded = {**probe, **_inside_support(model, {n: implied.get(n, np.nan) for n in new})}
    rig = {**current_map, **RIG_FIT}
    rig.update(probe_values(model, rig, new))
    out = [probe]
    for g in (seeded, rig):
        if all(g != o for o in out):
            out.append(g)
    return tuple(out)


def off_start(current_map: dict, effects: list[str]) -> dict:
    """The candidate model ``effects`` at the current fit ``current_map`` with its new
    parameters switched off: each at its default (the value that switches the effect
    off) if that lies inside its support, else at :data:`OFF_FRACTION` of its probe
    value (:func:`probe_values`)."""
    model = build_model(effects)
    new = [p for p in model.parameters() if p.name not in current_map]
    probe = probe_values(model, current_map, [p.name for p in new])
    out = dict(current_map)
    for par in new:
        out[par.name] = par.default if par.inside(par.default) else OFF_FRACTION * probe[par.name]
    return out


@dataclasses.dataclass(frozen=True)
class FitTask:
    """What one candidate fit needs (picklable; sent to a worker).

    Attributes
    ----------
    record : Experiment
    fit_window, score_window : (float, float)
        Windows [s]: the MAP uses ``fit_window``; ``score_window`` is held out.
    effects : tuple of str
        The model's effects, ``"axis:kind"`` (base effects first).
    guesses : tuple of dict
        Warm starts (physical parameter values).
    seed : int
    n_starts : int
        MAP starts (warm guesses included).
    draws : int
        Laplace draws simulated for the predictive.
    newton_steps : int
        Newton steps of the MAP polish (of the best start only).
    off, floor : dict or None, float or None
        The nested fallback (module docstring): the start with the new effects switched
        off (:func:`off_start`) and the current model's ``-log p`` at its MAP.
    priors : tuple of (str, Prior)
        Changes to the default priors (:meth:`PriorSet.updated`) of a discovery run, e.g.
        a parameter of a base effect, or of a candidate effect, fixed; the model takes
        those of its own parameters (:func:`model_priors`).
    refit : bool
        The guesses are fits of this model (e.g. on a shorter window): they are fitted
        again as the nested fallback is, at the substeps they need, from their initial
        state and residual scales, without a start grid (module docstring).
    """

    record: Experiment
    fit_window: tuple[float, float]
    score_window: tuple[float, float] | None
    effects: tuple[str, ...]
    guesses: tuple[dict, ...] = ()
    seed: int = 0
    n_starts: int = 3
    draws: int = 100
    newton_steps: int = 6
    off: dict | None = None
    floor: float | None = None
    priors: tuple[tuple[str, Prior], ...] = ()
    refit: bool = False


def model_priors(model, changes) -> PriorSet | None:
    """The default priors of ``model`` with those of ``changes`` (pairs ``(name, Prior)``,
    see :attr:`FitTask.priors`) that name its parameters, initial state or error scales
    applied (a change of a candidate effect's parameter holds where that effect is in the
    model); None (the defaults) if none apply."""
    default = PriorSet.default(model)
    own = {name: prior for name, prior in changes if name in default.names}
    return default.updated(model, own) if own else None


@dataclasses.dataclass(frozen=True, eq=False)
class Fitted:
    """A fitted model with its Laplace predictive over fitting and held-out window."""

    start: object
    params: dict
    y_sim: np.ndarray
    y_pred: np.ndarray
    sigma: np.ndarray
    seconds: float
    #: True if the MAP is the refit from "effect off" (module docstring).
    from_off: bool = False
    #: The importance resampling of the Laplace draws: ``pareto_k``, ``ess``, ``distinct``,
    #: ``predictive`` (``"laplace"``: the resampled draws; ``"map"``: the plug-in at the MAP).
    importance: dict = dataclasses.field(default_factory=dict)


def fitted_predictive(task: FitTask) -> Fitted:
    """MAP, Laplace draws and their simulations of ``task`` (module docstring)."""
    t0 = time.perf_counter()
    model = build_model(list(task.effects))
    problem = make_problem(task.record, task.fit_window, task.score_window, model=model,
                           priors=model_priors(model, task.priors), error="iid")  # fmt: skip
    start, from_off = _nested_map(problem, task)
    start = settle_edge(start, seed=task.seed, newton_steps=task.newton_steps)
    params = start.map_guess()
    sites, importance = importance_resample(start, task.draws, seed=task.seed)
    if not importance["pareto_k"] <= PARETO_K_MAX:  # not trusted: the plug-in predictive at the MAP
        sites = constrain_draws(start.density, np.repeat(start.x_map[None], task.draws, axis=0))
    importance["predictive"] = "laplace" if importance["pareto_k"] <= PARETO_K_MAX else "map"
    _, y_sim, y_pred = simulate_draws(start.problem, {k: np.asarray(v)[None] for k, v in sites.items()},
                                      np.arange(task.draws), seed=task.seed, want_ll=False)  # fmt: skip
    return Fitted(start, params, y_sim, y_pred, np.asarray(sites["sigma"]), time.perf_counter() - t0,
                  from_off, importance)  # fmt: skip


def _nested_map(problem, task: FitTask):
    """``(start, from_off)``: the MAP of ``task``'s starts, or of the nested fallback if
    that is better (module docstring).  A start whose MAP ends more than
    :data:`ABANDON_NATS` above the current model's is abandoned before its substeps and
    Laplace covariance (:class:`~heli_uq.inference.start.PoorBasin`) and the fallback
    fitted; if the fallback fails too, that start is finished after all."""

    def fit(guesses, n_starts, abandon_above=None, refit=task.refit):
        on = problem.with_substeps(guess_substeps(problem, guesses)) if refit else problem
        return prepare_start(on, n_starts=n_starts, seed=task.seed, guesses=guesses,
                             newton_steps=task.newton_steps, polish_best=1,
                             abandon_above=abandon_above, grid=not refit, from_fit=refit)  # fmt: skip

    def fallback():  # at the current fit's substeps, from its basin only (no grid start)
        return fit((task.off,), 1, refit=True)

    nested = task.off is not None and task.floor is not None
    try:
        start, error = fit(task.guesses, task.n_starts, task.floor + ABANDON_NATS if nested else None), None
    except ParameterError as exc:  # no start finite (or a poor basin): the fallback may still be
        start, error = None, exc
    if not nested:
        if error is not None:
            raise error
        return start, False
    if start is not None and start.map_value <= task.floor + NESTED_SLACK_NATS:
        return start, False
    try:
        again = fallback()
    except ParameterError:
        if isinstance(error, PoorBasin):
            return fit(task.guesses, task.n_starts), False
        if error is not None:
            raise error from None
        return start, False
    if start is None or again.map_value < start.map_value:
        return again, True
    return start, False


def fit_and_score(task: FitTask) -> dict:
    """Fit ``task``'s model and score it on the held-out window (module docstring); the
    task function of the candidate fits.  See :func:`score_fitted` for the result."""
    return score_fitted(fitted_predictive(task), task)


def score_fitted(fitted: Fitted, task: FitTask) -> dict:
    """The JSON-able record of a fitted model.

    Returns
    -------
    dict
        ``effects``, ``map`` (physical parameters and initial state), ``n_fitted`` (the
        coordinates the MAP fitted: free parameters, initial state and error scales), ``map_value``,
        ``log_evidence`` (the fitting window's Laplace evidence, :meth:`Start.log_evidence`),
        ``map_decrement``, ``solver_edge`` (:attr:`Start.solver_edge`, or None),
        ``substeps``, ``fit`` and ``score`` gap metrics (fitting and
        held-out window), ``block_scores`` [nats] and ``block_crps`` [rad] on the held-out
        window (:mod:`heli_uq.discovery.score`), ``laplace``
        (the importance resampling: ``pareto_k``, ``ess``, ``distinct``, ``predictive``),
        ``seconds``.
    """
    t0 = time.perf_counter()
    problem = fitted.start.problem
    windows = problem.windows()
    a, b = windows["train"]
    out = {"effects": list(task.effects), "map": fitted.params, "n_fitted": int(np.size(fitted.start.x_map)),
           "map_value": fitted.start.map_value, "log_evidence": fitted.start.log_evidence(),
           "map_decrement": fitted.start.map_decrement, "solver_edge": fitted.start.solver_edge,
           "substeps": problem.substeps, "off_start": fitted.from_off, "laplace": fitted.importance,
           "fit": gap_metrics(fitted.y_sim[:, a:b], fitted.y_pred[:, a:b], problem.y[a:b])}  # fmt: skip
    c, d = windows["test"]
    out["score"] = gap_metrics(fitted.y_sim[:, c:d], fitted.y_pred[:, c:d], problem.y[c:d])
    blocks = input_blocks(problem.u[c:d], problem.dt, min_blocks=MIN_BLOCKS)
    out["block_scores"] = block_scores(fitted.y_sim[:, c:d], fitted.sigma, problem.y[c:d],
                                       blocks).tolist()  # fmt: skip
    out["block_crps"] = block_crps(fitted.y_pred[:, c:d], problem.y[c:d], blocks).tolist()
    out["seconds"] = fitted.seconds + time.perf_counter() - t0
    return out
