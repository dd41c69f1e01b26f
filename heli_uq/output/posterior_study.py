"""The posterior study end to end: record -> problem -> MAP -> sampler -> InferenceData ->
diagnostics -> files.  The CLI's ``sample`` command is a thin layer over :func:`sample_posterior`.

Files written to ``out_dir``: ``posterior.nc`` (InferenceData, with the model description
in its attributes), ``summary.csv`` (arviz summary in physical units), ``summary.json``
(convergence, parameters with 95 % intervals, RMSE, coverage, the solver's accuracy at
the draw of highest density and the stiffest draw, the draws' stiffness against the solver's
stability limit, wall time), ``bands.png`` (posterior-predictive bands), ``map.json``
(:data:`MAP_FILE`: the MAP's parameters as ``simulate --params`` and ``sample --init`` read
them, so a larger model that nests this one can start from this fit), and ``chunks/``
(draws saved as they come).
"""

from __future__ import annotations

import json
import logging
import pathlib
import time

import numpy as np

from heli_uq.data.record import Experiment
from heli_uq.errors import ParameterError
from heli_uq.inference import (
    SAMPLERS,
    TARGET_ACCEPT,
    prepare_start,
    resume_obstacle,
    run_emcee,
    run_laplace,
    run_nuts,
    settle_edge,
)
from heli_uq.inference.draw_memory import check_draws_memory
from heli_uq.io import atomic_write_text
from heli_uq.log import progress_log
from heli_uq.model.heli_model import HeliModel
from heli_uq.model.tables import X0_NAMES
from heli_uq.model.terms.rigid_body import pitch_inertia, yaw_inertia
from heli_uq.output.diagnostics import draws_converged, start_distances, summarize, summary_table
from heli_uq.output.health import check_health
from heli_uq.output.inference_data import save_netcdf, to_inference_data
from heli_uq.output.last_layer import NETWORK_POSTERIORS, last_layer_setup
from heli_uq.output.network import band_widths, gain_trade_off, network_terms
from heli_uq.output.plots import plot_bands, save_figure
from heli_uq.probability.priors import PriorSet
from heli_uq.probability.problem import make_problem
from heli_uq.simulation.reference import solver_error
from heli_uq.simulation.stiffness import STABLE_STEP, stiffness_check, stiffness_rates

__all__ = ["sample_posterior", "bands_figure", "parameter_summary", "write_summary", "SOLVER_TOL",
           "MAP_FILE"]

#: The fixed-step solver must stay within this angle error [rad] of the adaptive reference
#: at the posterior mean; a larger error is reported as a warning.
SOLVER_TOL = 1e-4
#: The MAP's parameters in a run's directory: a flat JSON object ``{name: value [SI]}`` of
#: every model parameter (fixed ones at their fixed values), written when the MAP is found.
MAP_FILE = "map.json"
#: The files a posterior run writes in its directory besides its saved draws: a fresh run
#: removes another run's before it writes its own, so that an interrupted run never leaves
#: its map.json beside the other run's results (one run per directory).
RESULT_FILES = ("posterior.nc", "summary.json", "summary.csv", "bands.png", MAP_FILE)


def parameter_summary(idata, model: HeliModel, problem=None) -> dict:
    """``{name: {mean, sd, ci95: [lo, hi], unit}}`` of every sampled model parameter.

    Effect parameters carry the axis (``F_c_yaw``) and their bare name (``bare``).  With the
    sampled ``problem`` (its fixed values and reference pitch), a torque-type parameter
    (``scales_with_inertia`` with an ``axis``) also gets ``per_inertia``: ``{mean, ci95,
    unit, inertia}`` of its ratio to the inertia of its axis (``M11``, or ``M22`` at the
    coordinates' reference pitch ``theta_ref`` [rad], then stored too), the quantity the
    record identifies.  Its physical value is that ratio times the common scale, which only
    the priors place (``studies/notes/posterior.md``, "Where the common scale lands").
    """
    out = {}
    post = idata.posterior
    for par in model.parameters():
        if par.name not in post:
            continue
        v = np.asarray(post[par.name]).ravel()
        out[par.name] = dict(_interval(v), sd=float(v.std()), unit=par.unit, bare=par.bare)
    if problem is not None:
        inertia = _inertia_draws(post, problem)
        for par in model.parameters():
            if par.name in out and par.scales_with_inertia and par.axis is not None:
                ratio = np.asarray(post[par.name]).ravel() / inertia[par.axis]
                unit = "1" if par.unit == INERTIA_UNIT else f"({par.unit}) / ({INERTIA_UNIT})"
                out[par.name]["per_inertia"] = dict(_interval(ratio), unit=unit,
                                                    inertia=INERTIA_LABELS[par.axis])  # fmt: skip
                if par.axis == "yaw":
                    out[par.name]["per_inertia"]["theta_ref"] = float(problem.coords.yaw_theta_ref)
    return out


#: The inertia each axis' torque-type parameters are divided by in ``per_inertia``, and its unit.
INERTIA_LABELS = {"pitch": "M11", "yaw": "M22(theta_ref)"}
INERTIA_UNIT = "kg m^2"


def _interval(v: np.ndarray) -> dict:
    lo, hi = np.quantile(v, [0.025, 0.975])
    return {"mean": float(v.mean()), "ci95": [float(lo), float(hi)]}


def _inertia_draws(post, problem) -> dict:
    """Per-draw ``M11`` and ``M22(theta_ref)`` [kg m^2] (fixed parameters at their values)."""
    p = {n: np.asarray(post[n]).ravel() if n in post else float(prior.a)
         for n, prior in problem.priors.params.items()}  # fmt: skip
    return {"pitch": np.asarray(pitch_inertia(p)),
            "yaw": np.asarray(yaw_inertia(p, problem.coords.yaw_theta_ref))}  # fmt: skip


def _draw_point(problem, post, chain: int, draw: int) -> tuple[dict, list]:
    best = post.isel(chain=chain, draw=draw)
    params = {n: float(best[n]) if n in best else float(p.a)
              for n, p in problem.priors.params.items()}  # fmt: skip
    return params, [float(best[n]) for n in X0_NAMES]


def _solver_check(problem, idata) -> tuple[float | None, dict | None]:
    """``(error, stiffness)``: the fixed-step solver's angle error [rad] against the adaptive
    reference over the whole span, the larger of the draw of highest posterior density
    and the stiffest draw (``inf`` if the fixed-step solve fails, NaN if the reference
    does), and :func:`~heli_uq.simulation.stiffness.stiffness_check` of every draw.
    ``(None, None)`` for a model without stiff terms whose damping every draw's steps
    resolve (``r h`` within :data:`~heli_uq.simulation.stiffness.STABLE_STEP`), whose RK4
    error is below 1e-6 rad on the record at one substep (the tests check it); past it the
    most damped draw is compared too (at ``r h`` 2.5 the yaw is 1e-4 rad off)."""
    post = idata.posterior
    draws = {n: np.asarray(post[n]).ravel() for n in problem.priors.params if n in post}
    fixed = {n: float(p.a) for n, p in problem.priors.params.items() if n not in post}
    thetas = problem.y[: problem.n_train, 0]
    stiffness = stiffness_check(problem.model, draws, problem.substeps, problem.dt, fixed=fixed,
                                thetas=thetas)  # fmt: skip
    rates = stiffness_rates(problem.model, draws, fixed=fixed, thetas=thetas, decay=True)
    resolved = not np.nanmax(rates) * problem.dt / problem.substeps > STABLE_STEP
    if stiffness is None and resolved:
        return None, None
    lp = np.asarray(idata.sample_stats["lp"])
    points = {np.unravel_index(int(np.nanargmax(lp)), lp.shape)}
    if stiffness is not None:
        points.add(np.unravel_index(stiffness["stiffest"], lp.shape))
    if not resolved:
        points.add(np.unravel_index(int(np.nanargmax(rates)), lp.shape))
    errors = []
    for chain, draw in sorted(points):
        params, x0 = _draw_point(problem, post, int(chain), int(draw))
        try:
            errors.append(solver_error(params, x0, problem.u, problem.dt, model=problem.model,
                                       substeps=problem.substeps))  # fmt: skip
        except ParameterError:  # the reference itself failed: report, do not crash the study
            return float("nan"), stiffness
    error = max(errors)
    return (error if np.isfinite(error) else float("inf")), stiffness


def sample_posterior(record: Experiment, out_dir, *, model: HeliModel | None = None, train=None,
                     test=None, sampler="nuts", error="ar1", priors=None, chains=4, warmup=1000,
                     draws=1000, seed=0, resume=False, progress=True, walkers=None,
                     ensembles=None, n_starts=4, adapt_mass_matrix=True,
                     target_accept=TARGET_ACCEPT, substeps=None, log=None,
                     max_tree_depth=8, guesses=(), network_posterior="full", time_limit=None,
                     max_draws=None):  # fmt: skip
    """Run the whole posterior study and write its files; returns ``(idata, summary)``.

    Parameters
    ----------
    record : Experiment
    out_dir : path
    model : HeliModel, optional
        Default: the paper's model.
    train, test : (float, float), optional
        Windows in seconds (see :func:`heli_uq.probability.make_problem`).
    sampler : {"nuts", "emcee", "laplace"}
        ``laplace``: ``chains x draws`` independent draws of the Laplace approximation at
        the MAP, checked by Pareto k (:mod:`heli_uq.inference.laplace_sampler`; ``warmup``
        unused).  ``emcee`` runs ``ensembles`` (default ``chains``) independent ensembles of
        ``walkers`` walkers for ``warmup + draws`` steps each and keeps the last ``draws``.
    priors : PriorSet, optional
    resume : bool or "auto"
        Continue the run saved in ``out_dir`` (its MAP start and draws; refused under
        other settings).  ``"auto"`` (NUTS only): continue it if it was made with the same
        settings, else start afresh and say why, so running the same call again after an
        interruption or a finished run picks up its draws (what ``discover`` does); a
        last-layer network run always starts afresh (its hidden layers are trained first).
    adapt_mass_matrix, target_accept, max_tree_depth
        NUTS only, see :func:`heli_uq.inference.run_nuts`.
    time_limit : float, optional
        NUTS only: wall seconds from this call after which sampling stops with the draws
        made (at least :data:`~heli_uq.inference.nuts.MIN_DRAWS_AT_LIMIT` per chain, after
        the whole warm-up; :func:`heli_uq.inference.run_nuts`).
    max_draws : int, optional
        NUTS only: after ``draws``, go on a chunk at a time while R-hat or ESS fail their
        checks (:func:`~heli_uq.output.diagnostics.draws_converged`), up to ``max_draws``
        per chain and the time limit.
    substeps : int, optional
        RK4 substeps per sample (default: chosen from the model's stiffness).
    guesses : sequence of dict, optional
        MAP starts tried first (physical parameters and initial state, e.g. a fit of the
        same model on a nearby window), before the model's own start values.
    network_posterior : {"full", "last-layer"}
        For a model with a neural term: sample every weight (NUTS saturates its trees, slow),
        or fix the hidden layers at jointly trained values and sample the output weights
        with the physics (:mod:`heli_uq.output.last_layer`: fast, converges, but its band
        holds the curve less often); ignored without one.
    log : callable, optional
        Called with one line per stage (``"[  12 s] MAP: ..."``, elapsed time first);
        default: the ``logging`` INFO of this module (:mod:`heli_uq.log`).

    The summary's ``health`` (:func:`heli_uq.output.health.check_health`) says whether
    the result can be trusted; ``bands.png`` claims no coverage when it cannot.
    """
    if sampler not in SAMPLERS:
        raise ParameterError(f"sampler: expected one of {SAMPLERS}, found {sampler!r}")
    out = pathlib.Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()

    log = progress_log(log, __name__)

    def stage(text: str) -> None:
        log(f"[{time.perf_counter() - t0:5.0f} s] {text}")

    if network_posterior not in NETWORK_POSTERIORS:
        raise ParameterError(f"network_posterior: expected one of {NETWORK_POSTERIORS}, "
                             f"found {network_posterior!r}")  # fmt: skip
    auto = resume == "auto"
    if auto and sampler != "nuts":
        raise ParameterError(f"resume: 'auto' continues NUTS runs only, found sampler {sampler!r}")
    resume = False if auto else resume
    last_layer = None
    if network_posterior == "last-layer" and model is not None and network_terms(model) and not resume:
        priors = PriorSet.default(model) if priors is None else priors
        priors, trained, last_layer = last_layer_setup(record, train, test, model=model, priors=priors,
                                                       error=error, substeps=substeps, seed=seed,
                                                       guesses=guesses, log=stage)  # fmt: skip
        guesses = [*trained, *guesses]
        stage(f"last layer: V {last_layer['v_base']:.4g} -> {last_layer['v_trained']:.4g} rad^2 in "
              f"{last_layer['train_seconds']:.0f} s; hidden layers fixed")  # fmt: skip
    problem = make_problem(record, train, test, model=model, priors=priors, error=error,
                           substeps=substeps)  # fmt: skip
    nuts_settings = dict(chains=chains, warmup=warmup, draws=draws, seed=seed, max_tree_depth=max_tree_depth,
                         target_accept=target_accept, adapt_mass_matrix=adapt_mass_matrix)  # fmt: skip
    if auto and last_layer is None:
        why = resume_obstacle(problem, out, **nuts_settings)
        resume = why is None
        if why not in (None, "nothing to resume"):
            stage(f"cannot continue the draws saved in {out} ({why}): sampling afresh")
    per_chain = draws * (walkers or 2 * problem.coords.dim + 2 if sampler == "emcee" else 1)
    check_draws_memory(problem, chains * per_chain, f"draws: {chains} chains x {draws} draws"
                       + (" x walkers" if sampler == "emcee" else ""))  # fmt: skip
    start = None
    if not resume:
        stale = [out / f for f in RESULT_FILES if (out / f).is_file()]
        for path in stale:
            path.unlink()
        if stale:
            stage(f"a fresh run in {out}: removed the previous run's {', '.join(p.name for p in stale)}")
        stage(f"MAP: {n_starts} starts (least squares, then Newton on the log posterior; "
              "the first compiles the model)")  # fmt: skip
        start = prepare_start(problem, n_starts=max(n_starts, len(guesses)), seed=seed, log=stage,
                              guesses=guesses)  # fmt: skip
        start = settle_edge(start, seed=seed, log=stage)
        stage(f"MAP done: -log p = {start.map_value:.6g}, Newton decrement "
              f"{start.map_decrement:.2g}, {start.problem.substeps} substeps")  # fmt: skip
        atomic_write_text(out / MAP_FILE, json.dumps(start.map_point()[0], indent=1))
    if resume and sampler == "nuts":  # refused before it is announced as resumed
        resume_obstacle(problem, out, **nuts_settings, refuse=True)
    shape = (f"{chains} x {draws} independent draws of the Gaussian at the MAP" if sampler == "laplace"
             else f"{chains} chains x ({warmup} + {draws})")  # (Laplace has no warm-up)
    stage(f"{sampler}: {shape}" + (" (resumed from the saved chunks)" if resume else ""))
    if sampler == "nuts":
        left = None if time_limit is None else max(0.0, time_limit - (time.perf_counter() - t0))
        run = run_nuts(problem, out, **nuts_settings, resume=resume, progress=progress, start=start,
                       time_limit=left, max_draws=max_draws,
                       converged=draws_converged if max_draws is not None else None)  # fmt: skip
    elif sampler == "laplace":
        if resume:
            raise ParameterError("--resume: the Laplace sampler saves nothing to resume; run it again")
        run = run_laplace(problem, chains=chains, draws=draws, seed=seed, start=start)
    else:
        run = run_emcee(problem, out, ensembles=ensembles or chains, walkers=walkers,
                        steps=warmup + draws, burn=warmup, seed=seed, resume=resume,
                        progress=progress, start=start)  # fmt: skip
    if resume:  # the resumed run's own MAP: the directory's map.json may be another run's
        atomic_write_text(out / MAP_FILE, json.dumps(run.info["map_parameters"], indent=1))
    stage("posterior-predictive simulations and diagnostics")
    idata = to_inference_data(run, seed=seed)
    problem = run.problem
    summary = summarize(idata, wall_seconds=None)
    summary["parameters"] = parameter_summary(idata, problem.model, problem)
    x0_priors = dict(zip(X0_NAMES, problem.x0_priors()))
    summary["initial_state_priors"] = {n: p.describe() for n, p in x0_priors.items()}
    summary["start_distances"] = start_distances(idata, x0_priors)
    summary["solver_error_rad"], summary["stiffness"] = _solver_check(problem, idata)
    if summary["solver_error_rad"] is not None and not summary["solver_error_rad"] <= SOLVER_TOL:
        logging.getLogger(__name__).warning(
            f"the fixed-step solver ({problem.substeps} substeps) is "
            f"{summary['solver_error_rad']:.2g} rad from the adaptive reference at the draw of "
            f"highest density or the stiffest draw (tolerance {SOLVER_TOL:g}); rerun with more substeps")
    if last_layer is not None:
        summary["last_layer"] = last_layer
    networks = network_terms(problem.model)
    if networks:
        summary["gain_trade_off"] = {t.axis: gain_trade_off(idata, t.axis) for t in networks}
    of_u = [t.axis for t in networks if t.inputs == "u"]
    if of_u:
        summary["network_band_widths"] = {axis: band_widths(idata, axis) for axis in of_u}
    summary["health"] = check_health(summary, solver_tol=SOLVER_TOL)
    summary["wall_s"] = time.perf_counter() - t0
    stage("writing posterior.nc, summary.csv, summary.json, bands.png")
    save_netcdf(idata, out / "posterior.nc")
    atomic_write_text(out / "summary.csv", summary_table(idata).to_csv())
    write_summary(out, summary)
    save_figure(bands_figure(idata, summary), out / "bands.png")
    return idata, summary


def bands_figure(idata, summary: dict):
    """The posterior-predictive bands of a run (``bands.png``), from its InferenceData and
    its ``summary.json`` record (coverage per window, health flags, sampler, error model
    and model label), so a saved run's figure can be drawn again."""
    pp = idata.posterior_predictive["y_pred"]
    cd = idata.constant_data
    cov = {w: summary["windows"][w]["coverage90"] for w in summary["windows"]}
    return plot_bands(
        np.asarray(cd["time"]), np.asarray(pp).reshape((-1,) + pp.shape[2:]),
        np.asarray(cd["y_obs"]), train_mask=np.asarray(cd["train_mask"]),
        test_mask=np.asarray(cd["test_mask"]), coverage=cov,
        health=", ".join(summary["health"]["flags"]),
        title=(f"Posterior predictive ({summary['sampler']}, {summary['error_model']} errors, "
               f"{summary['model_label']}): {pathlib.Path(idata.posterior.attrs['source']).name}"),
    )  # fmt: skip


def write_summary(out, summary: dict) -> None:
    """Write ``summary`` to ``out/summary.json`` (atomically; arrays as lists)."""
    atomic_write_text(pathlib.Path(out) / "summary.json", json.dumps(summary, indent=1, default=_jsonable))


def _jsonable(obj):
    return np.asarray(obj).tolist()
