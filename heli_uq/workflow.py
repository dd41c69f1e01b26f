"""The posterior study end to end: record -> problem -> MAP -> sampler -> InferenceData ->
diagnostics -> files.  The CLI's ``sample`` command is a thin layer over :func:`sample_posterior`.

Files written to ``out_dir``: ``posterior.nc`` (InferenceData), ``summary.csv`` (arviz
summary in physical units), ``summary.json`` (convergence, RMSE, coverage, wall time),
``bands.png`` (posterior-predictive bands), and ``chunks/`` (draws saved as they come).
"""

from __future__ import annotations

import json
import pathlib
import time

import arviz as az
import numpy as np

from heli_uq.data import Experiment
from heli_uq.diagnostics import summarize
from heli_uq.errors import ParameterError
from heli_uq.inference import TARGET_ACCEPT, prepare_start, run_nuts
from heli_uq.io import atomic_write_text
from heli_uq.model import make_problem
from heli_uq.plots import plot_bands, save_figure
from heli_uq.results import save_netcdf, to_inference_data

__all__ = ["sample_posterior", "SAMPLERS"]

SAMPLERS = ("nuts", "emcee")


def sample_posterior(record: Experiment, out_dir, *, train=None, test=None, sampler="nuts",
                     error="ar1", priors=None, chains=4, warmup=1000, draws=1000, seed=0,
                     resume=False, progress=True, walkers=None, ensembles=None,
                     n_starts=4, adapt_mass_matrix=True, target_accept=TARGET_ACCEPT):  # fmt: skip
    """Run the whole posterior study and write its files; returns ``(idata, summary)``.

    Parameters
    ----------
    record : Experiment
    out_dir : path
    train, test : (float, float), optional
        Windows in seconds (see :func:`heli_uq.model.make_problem`).
    sampler : {"nuts", "emcee"}
        ``emcee`` runs ``ensembles`` (default ``chains``) independent ensembles of
        ``walkers`` walkers for ``warmup + draws`` steps each and keeps the last ``draws``.
    adapt_mass_matrix, target_accept
        NUTS only, see :func:`heli_uq.inference.run_nuts`.
    """
    if sampler not in SAMPLERS:
        raise ParameterError(f"--sampler: expected one of {SAMPLERS}, found {sampler!r}")
    out = pathlib.Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    problem = make_problem(record, train, test, priors=priors, error=error)
    start = None
    if not resume:
        start = prepare_start(problem, n_starts=n_starts, seed=seed)
    if sampler == "nuts":
        run = run_nuts(problem, out, chains=chains, warmup=warmup, draws=draws, seed=seed,
                       resume=resume, progress=progress, start=start,
                       adapt_mass_matrix=adapt_mass_matrix, target_accept=target_accept)  # fmt: skip
    else:
        from heli_uq.ensemble import run_emcee

        run = run_emcee(problem, out, ensembles=ensembles or chains, walkers=walkers,
                        steps=warmup + draws, burn=warmup, seed=seed, resume=resume,
                        progress=progress, start=start)  # fmt: skip
    idata = to_inference_data(problem, run, seed=seed)
    wall = time.perf_counter() - t0
    summary = summarize(idata, wall_seconds=wall)
    save_netcdf(idata, out / "posterior.nc")
    names = [v for v in idata.posterior.data_vars if v != "z"]
    atomic_write_text(out / "summary.csv", az.summary(idata, var_names=names).to_csv())
    atomic_write_text(out / "summary.json", json.dumps(summary, indent=1, default=_jsonable))
    pp = idata.posterior_predictive["y_pred"]
    cd = idata.constant_data
    cov = {w: summary["windows"][w]["coverage90"] for w in summary["windows"]}
    fig = plot_bands(
        np.asarray(cd["time"]), np.asarray(pp).reshape((-1,) + pp.shape[2:]),
        np.asarray(cd["y_obs"]), train_mask=np.asarray(cd["train_mask"]),
        test_mask=np.asarray(cd["test_mask"]), coverage=cov,
        title=f"Posterior predictive ({sampler}, {error} errors): {pathlib.Path(problem.source).name}",
    )  # fmt: skip
    save_figure(fig, out / "bands.png")
    return idata, summary


def _jsonable(obj):
    return np.asarray(obj).tolist()
