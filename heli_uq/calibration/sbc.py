"""Simulation-based calibration (SBC) of the package's NUTS posterior on synthetic records.

For each replicate ``r``: draw the paper's 12 parameters from the study prior (log-normal,
sigma_log ``prior_sd`` around Table 1; h ~ normal(0, ``h_sd``) or fixed at 0; g fixed)
and the parameters of any named effects (``SBCSettings.effects``) from their declared priors,
one residual scale [rad] for both angles from the model's ``sigma`` prior
(:data:`heli_uq.probability.priors.SIGMA_PRIOR`), simulate a ``duration`` s record with
random step inputs (:func:`heli_uq.simulation.synthetic_experiment`) and iid noise, run
the package's NUTS (MAP start, Laplace mass matrix) under the *same* parameter prior, and
record the rank of the true value of every sampled coordinate (the identifiable ratios of
:mod:`heli_uq.probability.coordinates`) among ``ranks`` thinned draws, and whether the
central 90 % interval of the draws covers it.  If the posterior is calibrated, every rank
is uniform on ``0..L`` and every 90 % interval covers the truth in 90 % of replicates.

A failed simulation of a prior draw is redrawn: the model gives such parameters zero
posterior mass (``solver_ok``), so the generating and the inference prior are the same
truncated prior.  The package's model centres the initial-angle prior on the first
measurement; the truth is drawn around the synthetic default start instead, so the two
priors differ whenever the noise sigma is not small next to ``X0_ANGLE_SD``.
``x0_prior="generator"`` (use it for SBC) gives the model explicit initial-state priors
(``normal(SYNTHETIC_X0, X0_ANGLE_SD)`` for the angles, ``X0_RATE_SD`` for the rates) so
the generating and the inference prior agree; ``"data"`` keeps the package's defaults,
centred on the record (its first angles, its measured initial rates).  The generator draws *one* residual
scale for both angles, the model has independent ``sigma_theta`` and ``sigma_psi``
priors; only the model parameters' coordinates are ranked.

Replicates are independent tasks of :func:`heli_uq.executor.run_tasks` (a Dask cluster
of worker processes, or serial).  Replicate ``r``'s randomness depends only on ``r`` and
the settings, so every scheduler gives the same replicates.  Each replicate is saved to
``out_dir/rep_XXXX.json`` as it finishes, and a rerun skips it (resume).

Layer 8 (imports everything below it except discovery and design).
"""

from __future__ import annotations

import json
import pathlib
import tempfile
import time
from collections.abc import Callable, Iterable

import jax
import numpy as np

from heli_uq.calibration.ranks import thinned_ranks
from heli_uq.calibration.settings import MODEL, SETTINGS_FILE, SBCSettings, check_settings
from heli_uq.errors import DataFormatError, ParameterError
from heli_uq.executor import TaskFailed, check_scheduler, run_tasks
from heli_uq.inference import prepare_start, run_nuts
from heli_uq.io import atomic_write_text
from heli_uq.log import progress_log
from heli_uq.model import TABLE1, X0_NAMES, HeliModel, Prior
from heli_uq.probability import Coordinates, PriorSet, make_problem
from heli_uq.probability.priors import SIGMA_PRIOR, X0_ANGLE_SD, X0_RATE_SD
from heli_uq.provenance import code_version
from heli_uq.simulation import SYNTHETIC_X0, synthetic_experiment

__all__ = ["SBCSettings", "study_priors", "draw_replicate", "run_replicate", "run_sbc",
           "load_replicates", "SETTINGS_FILE", "FAILED_FILE", "COVERAGE_LEVEL"]  # fmt: skip

#: The initial angles: with ``x0_prior="generator"`` every initial-state entry's prior is
#: the generator's, ``normal(SYNTHETIC_X0, X0_ANGLE_SD)`` for these, ``X0_RATE_SD`` for the rates.
X0_ANGLES = ("theta0", "psi0")
#: Prior draws tried per replicate before giving up (a draw whose simulation fails, or
#: whose angles leave |angle| < MAX_ANGLE [rad], is redrawn).
MAX_REDRAWS = 100
MAX_ANGLE = 50.0
COVERAGE_LEVEL = 0.90  # central posterior interval whose coverage of the truth is recorded
#: Replicates whose task raised, ``{"r": "<Type>: <message>"}`` (absent when none did).
FAILED_FILE = "failed.json"
#: MAP starts per replicate.
N_STARTS = 2
def study_priors(prior_sd: float, h_sd: float, x0_prior: str = "data",
                 model: HeliModel = MODEL) -> PriorSet:  # fmt: skip
    """The study prior: log-normal (sigma_log ``prior_sd``) around Table 1 for every
    parameter of positive or non-negative support, ``normal(0, h_sd)`` [m] (or fixed at 0
    when ``h_sd`` is 0) for the parameters of real support (the body-axis offset h), fixed
    parameters (g) as the model declares them; an effect's parameters (``model`` beyond
    the paper's) keep the priors their terms declare; with ``x0_prior="generator"`` the
    initial angles' prior is ``normal(SYNTHETIC_X0, X0_ANGLE_SD)`` instead of the
    data-centred default."""
    changes = {}
    for name in model.names:
        declared = model.parameter(name)
        if declared.prior.kind == "fixed" or name not in TABLE1:
            continue
        if declared.support == "real":
            changes[name] = Prior("normal", 0.0, h_sd) if h_sd > 0 else Prior("fixed", 0.0)
        else:
            changes[name] = Prior("lognormal", TABLE1[name], prior_sd)
    if x0_prior == "generator":
        changes.update({n: Prior("normal", SYNTHETIC_X0[i], X0_ANGLE_SD if n in X0_ANGLES else X0_RATE_SD)
                        for i, n in enumerate(X0_NAMES)})  # fmt: skip
    return PriorSet.default(model).updated(model, changes, where="sbc prior")


def draw_replicate(r: int, priors: PriorSet, duration: float, model: HeliModel = MODEL):
    """Truth and record of replicate ``r``, redrawn until the simulation is finite: the
    truth from the prior the sampler uses (:meth:`heli_uq.probability.Problem.draw_parameters`).

    Returns
    -------
    truth : dict
        Parameter name -> true value (physical units).
    sigma : float
        Noise sd of both angles [rad].
    x0 : ndarray, shape (4,)
        True initial state [rad, rad, rad/s, rad/s].
    record : Experiment
        ``round(duration / 0.01)`` samples.
    redraws : int
        Prior draws rejected before this one.
    """
    rng = np.random.default_rng([2026, r])
    for attempt in range(MAX_REDRAWS):
        truth = {n: float(priors.params[n].sample(rng)) for n in model.names}
        truth = model.draw_joint(truth, rng)  # a term's joint prior
        # the common scale's prior (Coordinates.joint_draws), from its own stream: a model
        # with only log-normal scaled priors keeps its ratios, so its records, exactly
        eps = np.random.default_rng([2026, r, attempt, 1]).standard_normal()
        truth = {n: float(v) for n, v in Coordinates(model, priors.params).joint_draws(truth, eps).items()}
        sigma = float(SIGMA_PRIOR.sample(rng))
        x0 = np.array(SYNTHETIC_X0) + rng.normal(size=4) * [X0_ANGLE_SD, X0_ANGLE_SD,
                                                           X0_RATE_SD, X0_RATE_SD]
        try:
            rec = synthetic_experiment(truth, x0, duration=duration, noise_std=(sigma, sigma),
                                       seed=int(rng.integers(2**31)), model=model)
        except DataFormatError:
            continue
        if np.all(np.abs(rec.y) < MAX_ANGLE):
            return truth, sigma, x0, rec, attempt
    raise RuntimeError(f"replicate {r}: no finite prior draw in {MAX_REDRAWS} attempts")


def _provenance(wall_s: float) -> dict:
    return {"heli_uq": code_version(), "jax": jax.__version__, "wall_s": float(wall_s),
            "time": time.strftime("%Y-%m-%dT%H:%M:%S")}  # fmt: skip


def run_replicate(task) -> dict:
    """One SBC replicate (the Dask task: top-level, its argument and result picklable).

    Parameters
    ----------
    task : (int, SBCSettings)
        Replicate index ``r`` (seeds its randomness) and the settings.

    Returns
    -------
    dict
        JSON-ready: ``replicate``, ``truth``, ``sigma`` [rad], ``x0``, ``redraws``,
        ``names`` (the ranked coordinates), ``L`` (draws ranked among), ``ranks``
        (name -> rank of the truth, 0..L), ``covered90`` (name -> bool), ``ess`` (name ->
        ESS of the draws), ``thin`` (every how many draws were ranked), sampler
        statistics (``divergences``, ``mean_steps``, ``step_size``, ``start_s``,
        ``nuts_s``, ``wall_s`` [s]), ``settings`` and ``provenance``.
    """
    r, settings = task
    t_rep = time.perf_counter()
    try:
        model = settings.model
        priors = study_priors(settings.prior_sd, settings.h_sd, settings.x0_prior, model)
        truth, sigma, x0, rec, redraws = draw_replicate(r, priors, settings.duration, model)
        problem = make_problem(rec, model=model, priors=priors, error="iid")
        coords = problem.coords
        z_true = coords.from_physical(truth)
        names = coords.sampled_names
        z_true = z_true[1:] if coords.marginal_scale else z_true
        t0 = time.perf_counter()
        with tempfile.TemporaryDirectory() as tmp:
            start = prepare_start(problem, n_starts=N_STARTS, seed=r, map_maxiter=settings.map_maxiter)
            t1 = time.perf_counter()
            run = run_nuts(problem, tmp, chains=settings.chains, warmup=settings.warmup,
                           draws=settings.draws, seed=r, progress=False, start=start,
                           adapt_mass_matrix=settings.adapt_mass_matrix)  # fmt: skip
        wall = time.perf_counter() - t0
        chains_z = np.asarray(run.samples["z"]).reshape(settings.chains, -1, len(names))
        ranks, big_l, thin, ess = thinned_ranks(chains_z, z_true, settings.ranks,
                                                thin_to_ess=settings.thin_to_ess)  # fmt: skip
        z = chains_z.reshape(-1, len(names))
        tail = (1 - COVERAGE_LEVEL) / 2
        out = {"replicate": r, "truth": truth, "sigma": sigma, "x0": x0.tolist(),
               "redraws": redraws, "names": list(names), "L": big_l, "wall_s": wall,
               "divergences": int(np.sum(run.stats["diverging"])),
               "mean_steps": float(np.mean(run.stats["num_steps"])),
               "step_size": np.asarray(run.info["step_size"]).tolist(), "start_s": t1 - t0,
               "nuts_s": wall - (t1 - t0), "map_grad_max": float(start.map_grad_max),
               "map_decrement": float(start.map_decrement), "settings": settings.to_dict(),
               "ess": dict(zip(names, ess.tolist())), "thin": thin,
               "ranks": {}, "covered90": {}}  # fmt: skip
        for i, n in enumerate(names):
            out["ranks"][n] = int(ranks[i])
            lo, hi = np.quantile(z[:, i], [tail, 1 - tail])
            out["covered90"][n] = bool(lo <= z_true[i] <= hi)
        out["provenance"] = _provenance(time.perf_counter() - t_rep)
        return out
    finally:
        # Every replicate compiles new closures (its data are constants of the jitted
        # functions); without this a long run exhausts memory in LLVM compilation.
        jax.clear_caches()


def _rep_path(out: pathlib.Path, r: int) -> pathlib.Path:
    return out / f"rep_{r:04d}.json"


def load_replicates(out_dir, replicates: Iterable[int] | None = None) -> list[dict]:
    """The stored replicates of ``out_dir`` (all, or those of ``replicates``), by index.

    Raises
    ------
    ParameterError
        When the replicates rank different coordinates (written by different package
        versions: they cannot be summarised together).
    """
    out = pathlib.Path(out_dir)
    if replicates is None:
        paths = sorted(out.glob("rep_*.json"))
    else:
        paths = [p for r in sorted(set(replicates)) if (p := _rep_path(out, r)).exists()]
    reps = [json.loads(p.read_text()) for p in paths]
    if len({tuple(r["names"]) for r in reps}) > 1:
        raise ParameterError(f"{out}: the replicates have different coordinates (written by different "
                             "package versions); keep them in separate output directories")  # fmt: skip
    return reps


def run_sbc(out_dir, settings: SBCSettings, replicates: int | Iterable[int], *, scheduler="local",
            workers: int | None = None, log: Callable[[str], None] | None = None) -> list[dict]:  # fmt: skip
    """Run the SBC replicates not yet stored in ``out_dir``; every stored one is returned.

    Parameters
    ----------
    out_dir : path
        Receives ``settings.json``, one ``rep_XXXX.json`` per finished replicate (written
        atomically as it finishes, so an interrupted run keeps it) and ``failed.json``
        (``{r: error}``) while any replicate has failed.
    settings : SBCSettings
        Must equal the settings ``out_dir`` was first run with.
    replicates : int or iterable of int
        ``n`` (replicates ``0..n-1``) or the replicate indices.
    scheduler : {"local", "serial"} or str
        See :func:`heli_uq.executor.run_tasks` (a Dask cluster address also works).
    workers : int, optional
        Worker processes of the local cluster (default: one per core, at most one per
        replicate to run).
    log : callable, optional
        Progress messages (default: the ``logging`` INFO of this module).

    Returns
    -------
    list of dict
        The stored replicates among ``replicates`` (see :func:`run_replicate`), by index;
        failed ones are missing (and listed in ``failed.json`` and the log).

    Raises
    ------
    ParameterError
        ``out_dir`` holds replicates run under other settings (the differing fields are
        named), or bad ``replicates``/``workers``.
    """
    log = progress_log(log, __name__)
    if not isinstance(settings, SBCSettings):
        raise ParameterError(f"settings: expected an SBCSettings, found {type(settings).__name__}")
    wanted = list(range(replicates)) if isinstance(replicates, int) else sorted(set(replicates))
    if any(not isinstance(r, int | np.integer) or r < 0 for r in wanted):
        raise ParameterError(f"replicates: expected a count or non-negative indices, found {replicates!r}")
    if workers is not None and not (isinstance(workers, int) and workers >= 1):
        raise ParameterError(f"workers: expected an integer >= 1, found {workers!r}")
    out = pathlib.Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    check_settings(out, settings)
    check_scheduler(scheduler)
    failed_path = out / FAILED_FILE
    failed = json.loads(failed_path.read_text()) if failed_path.exists() else {}
    todo = [int(r) for r in wanted if not _rep_path(out, r).exists()]
    if len(todo) < len(wanted):
        log(f"{out}: reusing {len(wanted) - len(todo)} stored replicate(s)")
    t0 = time.perf_counter()
    done = []

    def finished(r, result):
        if isinstance(result, TaskFailed):
            failed[str(r)] = result["error"]
            log(f"replicate {r}: FAILED ({result['error']})")
        else:
            atomic_write_text(_rep_path(out, r), json.dumps(result))
            failed.pop(str(r), None)
            done.append(r)
            log(f"replicate {r}: {result['wall_s']:.0f} s, {result['divergences']} divergences, "
                f"{result['mean_steps']:.0f} steps [{len(done)}/{len(todo)} in "
                f"{time.perf_counter() - t0:.0f} s]")  # fmt: skip
        if failed:
            atomic_write_text(failed_path, json.dumps(failed, indent=1, sort_keys=True))
        elif failed_path.exists():
            failed_path.unlink()

    if todo:
        n_workers = None if workers is None else min(workers, len(todo))
        how = ("serial" if scheduler == "serial"
               else f"Dask ({scheduler or 'local'}, workers: {n_workers or 'auto'})")  # fmt: skip
        log(f"{out}: running {len(todo)} replicate(s), {how}")
        run_tasks(run_replicate, {r: (r, settings) for r in todo}, scheduler=scheduler,
                  workers=n_workers, on_result=finished)  # fmt: skip
    still = sorted(int(r) for r in failed if int(r) in wanted)
    if still:
        log(f"{out}: {len(still)} replicate(s) failed: {still} (see {FAILED_FILE}; a rerun retries them)")
    return load_replicates(out, wanted)
