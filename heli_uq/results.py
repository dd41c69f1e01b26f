"""One result format: arviz InferenceData with named dims and coords, saved as NetCDF.

Groups: ``posterior`` (physical parameters by Table 2 name, initial state, ``sigma`` and
``tau``, ``rho`` per ``output``, sampling coordinates ``z`` per ``coordinate``), ``sample_stats``,
``log_likelihood`` (``y`` per observation, or per ``time_block`` of
:data:`LOGLIK_BLOCK` samples when a full record would make it larger than
:data:`MAX_LOGLIK_VALUES` values), ``prior``, ``posterior_predictive`` (``y_pred``,
``y_sim`` on a thinned subset of draws), ``observed_data`` (``y``) and
``constant_data`` (``u``, ``y_obs`` (all measured angles of the span), ``train_mask``,
``test_mask``).  ``time`` is in seconds,
``output`` is ``["theta", "psi"]``.
"""

from __future__ import annotations

import json
import os
import pathlib
import tempfile

import arviz as az
import jax
import jax.numpy as jnp
import numpy as np
from numpyro.infer import Predictive

from heli_uq.io import publish
from heli_uq.model import Problem, heli_model
from heli_uq.noise import pointwise_log_likelihood
from heli_uq.params import PARAM_NAMES

__all__ = ["to_inference_data", "posterior_predictive", "save_netcdf", "OUTPUTS"]

OUTPUTS = ["theta", "psi"]
MAX_LOGLIK_VALUES = 20_000_000
LOGLIK_BLOCK = 100
#: Posterior-predictive draws kept per chain (thinned evenly).
PP_DRAWS_PER_CHAIN = 100


def _thin_index(n: int, keep: int) -> np.ndarray:
    return np.unique(np.linspace(0, n - 1, min(n, keep)).round().astype(int))


def posterior_predictive(problem: Problem, samples: dict, *, draws_per_chain=PP_DRAWS_PER_CHAIN,
                         seed: int = 0):  # fmt: skip
    """Predictive angles for a thinned subset of draws.

    Returns
    -------
    draw_index : ndarray (D,)
        Which posterior draws were used.
    y_pred, y_sim : ndarrays, shape (chain, D, N, 2)
        With and without error-model noise [rad].
    """
    chains, n_draws = samples["z"].shape[:2]
    idx = _thin_index(n_draws, draws_per_chain)
    keep = ("z", "scale_noise", "theta0", "psi0", "omega_theta0", "omega_psi0", "sigma", "tau")
    flat = {k: jnp.asarray(v[:, idx].reshape((-1,) + v.shape[2:]))
            for k, v in samples.items() if k in keep}  # fmt: skip
    pred = Predictive(heli_model, posterior_samples=flat, return_sites=["y_pred", "y_sim"],
                      parallel=True)  # fmt: skip
    out = pred(jax.random.PRNGKey(seed), problem)
    shape = (chains, len(idx)) + out["y_pred"].shape[1:]
    return idx, np.asarray(out["y_pred"]).reshape(shape), np.asarray(out["y_sim"]).reshape(shape)


def _log_likelihood(problem: Problem, samples: dict, y_sim_all=None):
    """Pointwise log likelihood (chain, draw, time_train, output) for every draw."""
    n = problem.n_train
    y = jnp.asarray(problem.y[:n])
    flat = {k: jnp.asarray(v.reshape((-1,) + v.shape[2:])) for k, v in samples.items()
            if k in ("z", "scale_noise", "theta0", "psi0", "omega_theta0", "omega_psi0", "sigma",
                     "tau", "rho")}  # fmt: skip
    pred = Predictive(heli_model, posterior_samples=flat, return_sites=["y_sim"], parallel=True)
    sims = pred(jax.random.PRNGKey(0), problem)["y_sim"][:, :n]
    if "rho" in flat:
        ll = jax.vmap(lambda s, sg, r: pointwise_log_likelihood(s, y, sg, r))(
            sims, flat["sigma"], flat["rho"])
    else:
        ll = jax.vmap(lambda s, sg: pointwise_log_likelihood(s, y, sg))(sims, flat["sigma"])
    chains, draws = samples["z"].shape[:2]
    return np.asarray(ll).reshape(chains, draws, n, 2)


def to_inference_data(problem: Problem, run, *, prior_draws: int = 500, seed: int = 0,
                      pp_draws_per_chain: int = PP_DRAWS_PER_CHAIN) -> az.InferenceData:  # fmt: skip
    """Build the package's InferenceData from a :class:`~heli_uq.inference.SamplerRun`."""
    s = run.samples
    coords = {"output": OUTPUTS, "coordinate": list(problem.coords.sampled_names),
              "time": problem.t, "time_train": problem.t[: problem.n_train]}  # fmt: skip
    dims = {"sigma": ["output"], "rho": ["output"], "tau": ["output"], "z": ["coordinate"],
            "y": ["time_train", "output"], "y_pred": ["time", "output"],
            "y_sim": ["time", "output"], "u": ["time", "input"],
            "y_obs": ["time", "output"], "train_mask": ["time"], "test_mask": ["time"]}  # fmt: skip
    posterior = {k: np.asarray(v) for k, v in s.items()}
    stats = {k: np.asarray(v) for k, v in run.stats.items()}
    if "potential_energy" in stats:
        stats["lp"] = -stats.pop("potential_energy")
    if "num_steps" in stats:
        stats["n_steps"] = stats.pop("num_steps")
        stats["tree_depth"] = np.floor(np.log2(stats["n_steps"] + 1)).astype(int)
    if "accept_prob" in stats:
        stats["acceptance_rate"] = stats.pop("accept_prob")

    ll = _log_likelihood(problem, s)
    ll_dims, ll_coords = {"y": ["time_train", "output"]}, {}
    if ll.size > MAX_LOGLIK_VALUES:
        nb = problem.n_train // LOGLIK_BLOCK
        ll = ll[:, :, : nb * LOGLIK_BLOCK].reshape(ll.shape[0], ll.shape[1], nb, LOGLIK_BLOCK, 2)
        ll = ll.sum(axis=3)
        ll_dims = {"y": ["time_block", "output"]}
        ll_coords = {"time_block": problem.t[: nb * LOGLIK_BLOCK : LOGLIK_BLOCK]}

    idx, y_pred, y_sim = posterior_predictive(problem, s, draws_per_chain=pp_draws_per_chain,
                                              seed=seed)  # fmt: skip
    rng = np.random.default_rng(seed)
    prior = {n: p.sample(rng, (1, prior_draws)) for n, p in problem.coords.priors.items()
             if p.free}  # fmt: skip

    train_mask = np.zeros(len(problem.t), bool)
    train_mask[: problem.n_train] = True
    test_mask = np.zeros(len(problem.t), bool)
    if problem.test is not None:
        test_mask[problem.test[0] : problem.test[1]] = True
    idata = az.from_dict(
        posterior=posterior, sample_stats=stats, prior=prior,
        observed_data={"y": problem.y[: problem.n_train]},
        constant_data={"u": problem.u, "y_obs": problem.y, "train_mask": train_mask,
                       "test_mask": test_mask},
        coords={**coords, "input": ["u_theta", "u_psi"]}, dims=dims,
    )  # fmt: skip
    pp = az.from_dict(
        posterior_predictive={"y_pred": y_pred, "y_sim": y_sim},
        coords={"time": problem.t, "output": OUTPUTS, "draw": idx},
        dims={"y_pred": ["time", "output"], "y_sim": ["time", "output"]},
    )  # fmt: skip
    idata.extend(pp)
    idata.extend(az.from_dict(log_likelihood={"y": ll}, coords={**coords, **ll_coords},
                              dims=ll_dims))  # fmt: skip
    info = {k: v for k, v in run.info.items() if k not in ("x_map", "laplace_covariance")}
    idata.posterior.attrs.update({
        "sampler_info": json.dumps(info, default=lambda o: np.asarray(o).tolist()),
        "error_model": problem.error, "source": problem.source,
        "coordinates_strategy": problem.coords.resolved,
        "unidentified_coordinates": ",".join(problem.coords.unidentified),
        "free_parameters": ",".join(n for n in PARAM_NAMES if n in problem.coords.free),
    })  # fmt: skip
    return idata


def save_netcdf(idata: az.InferenceData, path) -> None:
    """Write ``idata`` to NetCDF atomically (temporary file + rename)."""
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(fd)
    try:
        idata.to_netcdf(tmp)
        publish(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
