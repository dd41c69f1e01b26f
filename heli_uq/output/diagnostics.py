"""Diagnostics from an InferenceData: convergence, fit and calibration, as one record.

Only reads the package's InferenceData (:mod:`heli_uq.output.inference_data`); never runs
inference.
Conventions (Vehtari et al. 2021): rank-normalised split R-hat <= 1.01, bulk and tail
ESS >= 400, no divergences after warm-up, E-BFMI >= 0.3.  One chain's R-hat is that of
its two halves (arviz has none for one chain).  Draws too few to measure R-hat or ESS
(arviz's NaN) fail the health check (:mod:`heli_uq.output.health`).  For emcee, R-hat and ESS are
computed across *independent ensembles* (each ensemble is one "chain"), never across
walkers of one ensemble, which are not independent; the integrated autocorrelation
time and acceptance per ensemble are reported as well.
"""

from __future__ import annotations

import contextlib
import json
import logging
import warnings

import arviz as az
import numpy as np
import xarray as xr

from heli_uq.output.divergences import divergence_sites
from heli_uq.output.network import is_network_weight
from heli_uq.probability.likelihood import loss_v
from heli_uq.simulation.physical import unphysical_draws as _unphysical

__all__ = ["RHAT_MAX", "ESS_MIN", "BFMI_MIN", "convergence", "draws_converged", "predictive_metrics",
           "start_distances",
           "predictive_checks",
           "summarize",
           "unphysical_draws", "summary_table"]

#: Posterior variables that are sampling internals, not physical quantities (left out of
#: ``summary.csv``; see :func:`summary_table`).
INTERNAL_SITES = ("z", "log_J_pitch", "scale_noise")
RHAT_MAX = 1.01
ESS_MIN = 400
BFMI_MIN = 0.3


@contextlib.contextmanager
def _quiet_arviz():
    """arviz's summaries without their noise: the RuntimeWarnings of stuck chains (it divides
    by zero; R-hat is inf) and its log line for draws too few to measure (NaN), both of
    which the health checks report in their own words."""
    logger = getattr(az, "_log", None) or logging.getLogger("arviz")  # arviz's own, unregistered
    level = logger.level
    logger.setLevel(logging.ERROR)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            yield
    finally:
        logger.setLevel(level)


def _diagnostic_vars(idata, weights: bool = False) -> list[str]:
    """Posterior variables whose R-hat/ESS judge convergence: every quantity except the
    sampling coordinates ``z`` and the raw network weights (their sign and permutation
    symmetries make them meaningless one by one; the network is judged by its output
    torque ``nn_torque_<axis>``).  ``weights=True``: the raw network weights only."""
    names = [v for v in idata.posterior.data_vars if v != "z"]
    return [v for v in names if is_network_weight(v) == weights]


def _worst(column, pick):
    values = column.dropna()
    if values.empty:
        return None
    return str(values.idxmax() if pick is max else values.idxmin())


def _rhat(post, summ):
    """R-hat per variable of the Dataset ``post``: arviz's (``summ``, its diagnostics) for
    several chains; for one chain, for which arviz gives NaN, that of its first and second
    halves as two chains (arviz splits each again), so a drift along the chain still shows
    (NaN below 8 draws)."""
    return summ["r_hat"] if post.sizes["chain"] > 1 else _halves_rhat(post)


def _halves_rhat(post):
    half = post.sizes["draw"] // 2
    first = post.isel(draw=slice(0, half))
    second = post.isel(draw=slice(half, 2 * half)).assign_coords(draw=first["draw"])
    halves = az.convert_to_inference_data(
        xr.concat([first, second], dim="chain").assign_coords(chain=[0, 1]))
    with _quiet_arviz():
        return az.summary(halves, kind="diagnostics")["r_hat"]


def convergence(idata) -> dict:
    """R-hat, ESS, divergences, tree depth, BFMI (NUTS) or acceptance and tau (emcee)."""
    names = _diagnostic_vars(idata)
    with _quiet_arviz():
        summ = az.summary(idata, var_names=names, kind="diagnostics")
    rhat = _rhat(idata.posterior[names], summ)
    info = json.loads(idata.posterior.attrs.get("sampler_info", "{}"))
    out = {
        "sampler": info.get("sampler"),
        "chains": int(idata.posterior.sizes["chain"]),
        "draws": int(idata.posterior.sizes["draw"]),
        "rhat_max": float(rhat.max()),
        "ess_bulk_min": float(summ["ess_bulk"].min()),
        "ess_tail_min": float(summ["ess_tail"].min()),
        "worst_rhat_variable": _worst(rhat, max),
        "worst_ess_variable": _worst(summ["ess_bulk"], min),
    }
    weights = _diagnostic_vars(idata, weights=True)
    if weights:  # reported, not judged (see _diagnostic_vars)
        with _quiet_arviz():
            rw = az.summary(idata, var_names=weights, kind="diagnostics")["r_hat"]
        out["rhat_max_network_weights"] = float(rw.max())
        torques = [v for v in names if v.startswith("nn_torque_")]
        out["rhat_max_network_torque"] = float(summ.loc[[i for i in summ.index
                                                        if i.split("[")[0] in torques], "r_hat"].max())
    for key in ("map_value", "map_seconds", "warmup_seconds", "map_decrement", "map_decrement_max",
                "target_accept", "substeps", "wall_coordinates", "wall_sides", "max_tree_depth",
                "metric_factors", "draws_requested", "draws_extended_from", "warmup_requested", "warmup",
                "adapt_mass_matrix", "solver_edge"):
        if key in info:
            out[key] = info[key]
    stats = getattr(idata, "sample_stats", None)
    if stats is not None and "diverging" in stats:
        out["divergences"] = int(stats["diverging"].sum())
        sites = divergence_sites(idata)
        if sites:  # by chain and by position: where to look (divergences.py)
            out["divergence_sites"] = sites
        depth = int(info.get("max_tree_depth", 10))
        out["tree_depth_saturation"] = float((stats["tree_depth"] >= depth).mean())
        out["mean_leapfrog_steps"] = float(stats["n_steps"].mean())
        out["bfmi_min"] = float(np.min(az.bfmi(idata)))
        out["step_size"] = info.get("step_size")
    else:
        out["divergences"] = 0
        for key in ("acceptance", "tau", "ess_emcee", "pareto_k", "failed_draws", "warnings"):
            if key in info:
                out[key] = info[key]
    out["converged"] = bool(
        out["rhat_max"] <= RHAT_MAX and out["ess_bulk_min"] >= ESS_MIN
        and out["ess_tail_min"] >= ESS_MIN and out["divergences"] == 0
        and out.get("bfmi_min", 1.0) >= BFMI_MIN
    )  # fmt: skip
    return out


def draws_converged(samples: dict) -> bool:
    """R-hat and bulk and tail ESS of draws that pass :data:`RHAT_MAX` and :data:`ESS_MIN`,
    judged on the sampled quantities :func:`convergence` judges (every one but the sampling
    coordinates ``z`` and the raw network weights; a network's output torque, which
    :func:`convergence` also judges, is computed only afterwards).

    Parameters
    ----------
    samples : dict
        Named draws, arrays of shape (chains, draws, ...) (what NUTS has made so far:
        :func:`heli_uq.inference.run_nuts` asks this to decide whether to go on).
    """
    names = [k for k in samples if k != "z" and not is_network_weight(k)]
    posterior = az.convert_to_dataset({k: np.asarray(samples[k]) for k in names})
    with _quiet_arviz():
        summ = az.summary(posterior, kind="diagnostics")
    return bool(_rhat(posterior, summ).max() <= RHAT_MAX and summ["ess_bulk"].min() >= ESS_MIN
                and summ["ess_tail"].min() >= ESS_MIN)  # fmt: skip


def summary_table(idata):
    """arviz's summary (mean, sd, 94 % HDI, MCSE, ESS, R-hat) of every physical quantity in
    the posterior, in SI units and at full precision (no rounding: a parameter of 1e-3 keeps
    its digits).  The sampling coordinates ``z`` are left out: they are internal (log-ratios
    to the inertias, whitened by the MAP's Laplace approximation) and listed in
    ``summary.json`` only through their diagnostics, as are the other internal sites
    (:data:`INTERNAL_SITES`: ``log_J_pitch``, the log of the unidentified common inertia
    scale M11, drawn from its conditional prior, and ``scale_noise``, the standard normal
    draw behind it)."""
    names = [v for v in _diagnostic_vars(idata) if v not in INTERNAL_SITES]
    with _quiet_arviz():
        return az.summary(idata, var_names=names, round_to="none")


def _windows(idata) -> dict[str, np.ndarray]:
    cd = idata.constant_data
    out = {"train": np.asarray(cd["train_mask"], bool)}
    test = np.asarray(cd["test_mask"], bool)
    if test.any():
        out["test"] = test
    return out


def predictive_metrics(y_sim: np.ndarray, y_pred: np.ndarray, y_obs: np.ndarray) -> dict:
    """Fit and calibration of predictive draws on one window.

    Parameters
    ----------
    y_sim : array, shape (S, N, 2)
        Simulated angles (theta, psi) [rad] of S posterior draws (NaN where a solve failed).
    y_pred : array, shape (S, N, 2)
        The same with the error model's noise [rad].
    y_obs : array, shape (N, 2)
        Measured angles [rad].

    Returns
    -------
    dict
        ``rmse``, ``coverage90``, ``coverage50`` (each ``{theta, psi}``): RMSE [rad] of the
        mean simulation and the fraction of ``y_obs`` inside the central 90 % / 50 %
        predictive band; ``loss_v`` [rad^2]: the paper's loss of the mean simulation;
        ``draws_failed``, ``draws``: how many of the S draws did not simulate (NaN).  The
        other numbers are of the draws that simulate: with any failed, they describe a
        predictive distribution without its failures (the health check flags them), and
        with all failed they are NaN.
    """
    y_sim, y_pred = np.asarray(y_sim, dtype=float), np.asarray(y_pred, dtype=float)
    y_obs = np.asarray(y_obs, dtype=float)
    n_failed = int(np.isnan(y_pred).any(axis=(1, 2)).sum())
    if n_failed == y_pred.shape[0]:
        nan = {"theta": float("nan"), "psi": float("nan")}
        return {"rmse": nan, "coverage90": dict(nan), "coverage50": dict(nan), "loss_v": float("nan"),
                "draws_failed": n_failed, "draws": n_failed}  # fmt: skip
    failed = n_failed > 0
    q = (np.nanquantile if failed else np.quantile)(y_pred, [0.05, 0.25, 0.75, 0.95], axis=0)
    mean_sim = (np.nanmean if failed else np.mean)(y_sim, axis=0)
    out = {"rmse": {}, "coverage90": {}, "coverage50": {}}
    for j, name in enumerate(("theta", "psi")):
        obs = y_obs[:, j]
        out["rmse"][name] = float(np.sqrt(np.mean((mean_sim[:, j] - obs) ** 2)))
        out["coverage90"][name] = float(np.mean((obs >= q[0, :, j]) & (obs <= q[3, :, j])))
        out["coverage50"][name] = float(np.mean((obs >= q[1, :, j]) & (obs <= q[2, :, j])))
    out["loss_v"] = float(loss_v(mean_sim, y_obs))
    out["draws_failed"], out["draws"] = n_failed, int(y_pred.shape[0])
    return out


def predictive_checks(idata) -> dict:
    """RMSE [rad] of the posterior-mean simulation, coverage of the 50 % and 90 % bands,
    and the paper's loss V, per window (``train``, ``test``) and output
    (:func:`predictive_metrics`)."""
    pp = idata.posterior_predictive
    y_pred = np.asarray(pp["y_pred"]).reshape((-1,) + pp["y_pred"].shape[2:])
    y_sim = np.asarray(pp["y_sim"]).reshape((-1,) + pp["y_sim"].shape[2:])
    y_obs = np.asarray(idata.constant_data["y_obs"])
    out = {}
    for window, mask in _windows(idata).items():
        res = predictive_metrics(y_sim[:, mask], y_pred[:, mask], y_obs[mask])
        res["loss_v_posterior_mean_sim"] = res.pop("loss_v")
        res["loss_v_mean_over_draws"] = float(np.nanmean([loss_v(s[mask], y_obs[mask]) for s in y_sim])
                                              if res["draws_failed"] < res["draws"] else np.nan)
        res["n_samples"] = int(mask.sum())
        out[window] = res
    return out


def unphysical_draws(idata) -> dict:
    """``{"count", "of"}``: posterior-predictive simulations (``y_sim``) that leave the
    physical range (:func:`heli_uq.simulation.physical.unphysical_draws`)."""
    y_sim = np.asarray(idata.posterior_predictive["y_sim"])
    bad = _unphysical(y_sim.reshape((-1,) + y_sim.shape[2:]))
    return {"count": int(bad.sum()), "of": int(bad.size)}


def start_distances(idata, priors: dict) -> dict:
    """How far the posterior of each initial angle sits from its prior, for the health
    check's note on a model that cannot start where the record does.

    Parameters
    ----------
    idata : arviz.InferenceData
        With ``theta0`` and ``psi0`` [rad] in its posterior where they were sampled.
    priors : dict of str to Prior
        The initial state's priors by name (:meth:`heli_uq.probability.Problem.x0_priors`).

    Returns
    -------
    dict
        Per sampled angle with a normal prior: ``posterior_mean`` [rad], ``prior_mean``,
        ``prior_sd`` [rad] and ``prior_sds``, the distance in prior standard deviations.
    """
    out = {}
    for name in ("theta0", "psi0"):
        prior = priors.get(name)
        if name not in idata.posterior or prior is None or prior.kind != "normal":
            continue
        mean = float(idata.posterior[name].mean())
        out[name] = {"posterior_mean": mean, "prior_mean": float(prior.a), "prior_sd": float(prior.b),
                     "prior_sds": abs(mean - float(prior.a)) / float(prior.b)}  # fmt: skip
    return out


def summarize(idata, *, wall_seconds: float | None = None) -> dict:
    """The ``summary.json`` record: convergence + predictive checks (+ wall time)."""
    conv = convergence(idata)
    checks = predictive_checks(idata)
    out = dict(conv)
    out["unphysical_draws"] = unphysical_draws(idata)
    out["windows"] = checks
    out["rmse"] = checks["train"]["rmse"]
    out["coverage90"] = checks["train"]["coverage90"]
    if "test" in checks:
        out["rmse_test"] = checks["test"]["rmse"]
        out["coverage90_test"] = checks["test"]["coverage90"]
    attrs = idata.posterior.attrs
    out["error_model"] = attrs.get("error_model")
    out["model"] = json.loads(attrs["model"]) if "model" in attrs else None
    out["model_label"] = attrs.get("model_label")
    out["unidentified_coordinates"] = attrs.get("unidentified_coordinates")
    if wall_seconds is not None:
        out["wall_s"] = float(wall_seconds)
    return out
