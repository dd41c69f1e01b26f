"""One result format: arviz InferenceData with named dims and coords, saved as NetCDF.

Groups:

* ``posterior``: the model's free parameters by name (SI), the initial state, ``sigma``,
  ``tau``, ``rho`` and ``timing`` per ``output`` (as the error model has them), the
  sampling coordinates ``z`` per ``coordinate``;
  for a hybrid model also ``nn_torque_<axis>``, the network's output torque [N m] on the
  grid of :mod:`heli_uq.output.network` (dim ``nn_point_<axis>``, its inputs as coords;
  a network of the voltages also ``nn_torque_<axis>_unseen`` at the span's voltage pairs
  the training window never holds); for a ``gp_torque`` term ``gp_torque_<axis>``, its
  torque [N m] at its voltage pairs (dim ``gp_pair_<axis>``, coords the voltages and
  ``fitted``; :mod:`heli_uq.output.gp`);
* ``sample_stats``; ``prior`` (draws of every free prior, by name);
* ``log_likelihood``: ``y``, the pointwise log likelihood of the training window per
  ``time_block`` of ``loglik_block`` samples (sums over each block; a block of 1 is the
  per-sample value) and ``output``, on a thinned subset of draws (coordinate ``draw``);
* ``posterior_predictive``: ``y_pred`` (with error-model noise) and ``y_sim`` on a
  thinned subset of draws, over the whole span (training then test window), float32;
* ``observed_data`` (``y``) and ``constant_data`` (``u``, ``y_obs``, ``train_mask``,
  ``test_mask``).

``time`` is in seconds, ``output`` is ``["theta", "psi"]``.  The ``posterior`` attributes
hold the model description (``model``, read back by :func:`load_posterior`), the priors,
the error model, the substeps and the sampler facts.

Memory stays bounded whatever the number of draws and samples: each used draw is
simulated **once**, in batches of :data:`SIM_BATCH` draws, and only the thinned subsets
and block sums are kept (at most :data:`MAX_LOGLIK_VALUES` log-likelihood values and
:data:`PP_DRAWS` predictive draws).  The file stays compact too (:func:`save_netcdf`:
zlib with the byte-shuffle filter; the predictive angles in float32 at a resolution of
:data:`PREDICTIVE_RESOLUTION`, far below the rig's 3 mrad noise; the log likelihood in
float64, so its
block sums add up to the model's log likelihood exactly); each thinned group's
``thinned`` attribute says what was kept.  A default ``heli-uq run`` (4 x 500 draws,
13,100 samples) writes about 25 MB (``tests/test_trust.py`` checks the bound of 30 MB).
"""

from __future__ import annotations

import json
import math
import os
import pathlib
import tempfile

import arviz as az
import jax
import jax.numpy as jnp
import numpy as np

from heli_uq.errors import DataFormatError
from heli_uq.io import publish
from heli_uq.model.spec import model_from_description
from heli_uq.model.tables import X0_NAMES
from heli_uq.output.gp import gp_torques
from heli_uq.output.network import UNSEEN, network_torques
from heli_uq.probability.likelihood import pointwise_log_likelihood
from heli_uq.probability.noise import ar1_noise
from heli_uq.probability.priors import NOISE_KINDS, OUTPUTS
from heli_uq.probability.problem import training_data

__all__ = ["to_inference_data", "save_netcdf", "load_posterior", "OUTPUTS", "simulate_draws"]

#: Largest number of values of the log-likelihood group (8 MB in float64; the default run
#: keeps 4 x 500 draws in blocks of 37 samples, 0.37 s).
MAX_LOGLIK_VALUES = 1_000_000
#: Log-likelihood draws kept per chain (thinned evenly).
LOGLIK_DRAWS_PER_CHAIN = 1000
#: Posterior-predictive draws kept in total (thinned evenly over the chains).
PP_DRAWS = 200
#: Resolution of the stored predictive angles [rad]: 2^-16 rad = 1.5e-5 rad (9e-4 deg),
#: 200 times finer than the rig's 3 mrad noise.  Rounding to it zeroes the low mantissa
#: bits, which shrinks the compressed y_sim by 40 % and y_pred by 30 %.
PREDICTIVE_RESOLUTION = 2.0**-16
#: Draws simulated at once.
SIM_BATCH = 128
#: Sampled sites that duplicate a per-output vector (``sigma``, ``tau``, ``timing``).
_SCALAR_NOISE = tuple(f"{k}_{o}" for k in NOISE_KINDS for o in OUTPUTS)


def _thin_index(n: int, keep: int) -> np.ndarray:
    return np.unique(np.linspace(0, n - 1, min(n, keep)).round().astype(int))


def _draw_inputs(problem, samples: dict, flat_index: np.ndarray):
    """``(params, x0, errors)`` of the flat draws ``flat_index`` (chain-major); ``errors``
    maps ``sigma`` and, as the error model has them, ``rho`` and ``timing`` to (S, 2)."""

    def pick(v):
        return np.asarray(v).reshape((-1,) + np.shape(v)[2:])[flat_index]

    params = {}
    for par in problem.model.parameters():
        prior = problem.priors.params[par.name]
        params[par.name] = pick(samples[par.name]) if prior.free else np.full(flat_index.size, prior.a)
    x0 = np.column_stack([pick(samples[n]) for n in X0_NAMES])
    errors = {"sigma": pick(samples["sigma"])}
    if problem.ar1:
        errors["rho"] = pick(samples["rho"])
    if problem.timing:
        errors["timing"] = pick(samples["timing"])
    return params, x0, errors


def simulate_draws(problem, samples: dict, flat_index: np.ndarray, *, seed: int = 0,
                   block: int = 1, want_ll: bool = True, want_pred: bool = True):  # fmt: skip
    """Simulate each draw of ``flat_index`` once over the whole span, in batches.

    Returns ``(ll, y_sim, y_pred)``: the training window's pointwise log likelihood summed
    over blocks of ``block`` samples (S, n_blocks, 2); simulated angles (S, N, 2) and
    predictive angles with error-model noise (S, N, 2), float32 rounded to
    :data:`PREDICTIVE_RESOLUTION`; ``None`` where not wanted.
    A draw whose solve fails has ``-inf`` log likelihood and NaN angles.
    """
    n, n_train = problem.u.shape[0], problem.n_train
    n_blocks = n_train // block
    y_train = jnp.asarray(problem.y[:n_train])

    @jax.jit
    def one(params, x0, errors, key):
        sol = problem.solve(params, x0)
        sim = jnp.where(sol.ok, sol.ys[:, :2], jnp.nan)
        sigma, rho, timing = errors["sigma"], errors.get("rho"), errors.get("timing")
        rate = jnp.where(sol.ok, sol.ys[:, 2:4], 0.0) if timing is not None else None
        ll = pointwise_log_likelihood(sim[:n_train], y_train, sigma, rho, timing,
                                      None if rate is None else rate[:n_train])  # fmt: skip
        ll = jnp.where(sol.ok, ll, -jnp.inf)[: n_blocks * block].reshape(n_blocks, block, 2).sum(1)
        return ll, sim, sim + ar1_noise(key, n, sigma, rho, timing, rate)

    batched = jax.jit(jax.vmap(one))
    keys = jax.random.split(jax.random.PRNGKey(seed), flat_index.size)
    size = min(SIM_BATCH, flat_index.size)  # one compiled batch shape
    out_ll, out_sim, out_pred = [], [], []
    for i in range(0, flat_index.size, size):
        idx = flat_index[i : i + size]
        pad = size - idx.size
        full = np.concatenate([idx, np.repeat(idx[-1:], pad)]) if pad else idx
        params, x0, errors = _draw_inputs(problem, samples, full)
        ll, sim, pred = batched({k: jnp.asarray(v) for k, v in params.items()}, jnp.asarray(x0),
                                {k: jnp.asarray(v) for k, v in errors.items()},
                                keys[i : i + size] if not pad else
                                jnp.concatenate([keys[i:], jnp.repeat(keys[-1:], pad, 0)]))  # fmt: skip
        keep = size - pad
        if want_ll:
            out_ll.append(np.asarray(ll)[:keep])
        if want_pred:
            out_sim.append(_stored(sim)[:keep])
            out_pred.append(_stored(pred)[:keep])
    ll = np.concatenate(out_ll) if want_ll else None
    return (ll, np.concatenate(out_sim) if want_pred else None,
            np.concatenate(out_pred) if want_pred else None)  # fmt: skip


def _stored(angles) -> np.ndarray:
    """Angles as stored: rounded to :data:`PREDICTIVE_RESOLUTION`, float32."""
    a = np.asarray(angles, dtype=np.float64)
    return (np.round(a / PREDICTIVE_RESOLUTION) * PREDICTIVE_RESOLUTION).astype(np.float32)


def _loglik_layout(chains: int, draws: int, n_train: int, max_values: int):
    """Thinned draw index per chain and the block length that keep the group bounded."""
    idx = _thin_index(draws, LOGLIK_DRAWS_PER_CHAIN)
    block = max(1, math.ceil(chains * idx.size * n_train * 2 / max_values))
    return idx, min(block, n_train)


def to_inference_data(run, *, prior_draws: int = 500, seed: int = 0, pp_draws: int = PP_DRAWS,
                      max_loglik_values: int = MAX_LOGLIK_VALUES) -> az.InferenceData:  # fmt: skip
    """Build the package's InferenceData from a :class:`~heli_uq.inference.SamplerRun`."""
    problem = run.problem
    s = {k: np.asarray(v) for k, v in run.samples.items() if k not in _SCALAR_NOISE}
    chains, draws = s["z"].shape[:2]
    n_train = problem.n_train
    coords = {"output": list(OUTPUTS), "coordinate": list(problem.coords.sampled_names),
              "time": problem.t, "time_train": problem.t[:n_train]}  # fmt: skip
    dims = {"sigma": ["output"], "rho": ["output"], "tau": ["output"], "timing": ["output"],
            "z": ["coordinate"],
            "u": ["time", "input"], "y_obs": ["time", "output"], "train_mask": ["time"],
            "test_mask": ["time"], "y": ["time_train", "output"]}  # fmt: skip
    stats = {k: np.asarray(v) for k, v in run.stats.items()}
    if "potential_energy" in stats:
        stats["lp"] = -stats.pop("potential_energy")
    if "num_steps" in stats:
        stats["n_steps"] = stats.pop("num_steps")
        stats["tree_depth"] = np.floor(np.log2(stats["n_steps"] + 1)).astype(int)
    if "accept_prob" in stats:
        stats["acceptance_rate"] = stats.pop("accept_prob")

    # One simulation per used draw: the log-likelihood subset and the predictive subset.
    ll_idx, block = _loglik_layout(chains, draws, n_train, max_loglik_values)
    ll_flat = (np.arange(chains)[:, None] * draws + ll_idx[None, :]).ravel()
    pp_per_chain = max(1, pp_draws // chains)
    pp_idx = _thin_index(draws, pp_per_chain)
    pp_flat = (np.arange(chains)[:, None] * draws + pp_idx[None, :]).ravel()
    union, inverse = np.unique(np.concatenate([ll_flat, pp_flat]), return_inverse=True)
    ll_all, sim_all, pred_all = simulate_draws(problem, run.samples, union, seed=seed, block=block)
    ll = ll_all[inverse[: ll_flat.size]].reshape(chains, ll_idx.size, -1, 2)
    y_sim = sim_all[inverse[ll_flat.size:]].reshape(chains, pp_idx.size, -1, 2)
    y_pred = pred_all[inverse[ll_flat.size:]].reshape(chains, pp_idx.size, -1, 2)

    rng = np.random.default_rng(seed)
    prior = problem.draw_parameters(rng, (1, prior_draws))
    masks = problem.masks()
    idata = az.from_dict(
        posterior=s, sample_stats=stats, prior=prior,
        observed_data={"y": problem.y[:n_train]},
        constant_data={"u": problem.u, "y_obs": problem.y, "train_mask": masks["train"],
                       "test_mask": masks["test"]},
        coords={**coords, "input": ["u_theta", "u_psi"]}, dims=dims,
    )  # fmt: skip
    idata.extend(az.from_dict(
        posterior_predictive={"y_pred": y_pred, "y_sim": y_sim},
        coords={"time": problem.t, "output": list(OUTPUTS), "draw": pp_idx},
        dims={"y_pred": ["time", "output"], "y_sim": ["time", "output"]}))  # fmt: skip
    n_blocks = ll.shape[2]
    idata.extend(az.from_dict(
        log_likelihood={"y": ll},
        coords={"draw": ll_idx, "output": list(OUTPUTS),
                "time_block": problem.t[: n_blocks * block : block]},
        dims={"y": ["time_block", "output"]}))  # fmt: skip
    idata.log_likelihood.attrs["loglik_block"] = int(block)
    idata.log_likelihood.attrs["thinned"] = (
        f"{ll_idx.size} of {draws} draws per chain (evenly spaced; their indices are the 'draw' "
        f"coordinate); each value sums the pointwise log likelihood over {block} samples "
        "(coordinate 'time_block': the first time of each block)")  # fmt: skip
    idata.posterior_predictive.attrs["thinned"] = (
        f"{pp_idx.size} of {draws} draws per chain (evenly spaced; their indices are the 'draw' "
        "coordinate); y_pred and y_sim stored as float32, rounded to multiples of "
        f"{PREDICTIVE_RESOLUTION:.3g} rad")  # fmt: skip
    _add_network_torques(idata, problem, run.samples)
    _add_gp_torques(idata, problem, run.samples)
    info = {k: v for k, v in run.info.items() if k not in ("x_map", "covariance")}
    idata.posterior.attrs.update({
        "sampler_info": json.dumps(info, default=lambda o: np.asarray(o).tolist()),
        "model": json.dumps(problem.model.describe()), "model_label": problem.model.label,
        "priors": json.dumps(problem.priors.to_json()),
        "error_model": problem.error, "source": problem.source, "substeps": problem.substeps,
        "coordinates_strategy": problem.coords.resolved,
        "unidentified_coordinates": ",".join(problem.coords.unidentified),
        "free_parameters": ",".join(problem.coords.free),
        **training_data(problem),  # the data it saw: a report on other data is refused
    })  # fmt: skip
    return idata


def _add_gp_torques(idata: az.InferenceData, problem, samples: dict) -> None:
    """``gp_torque_<axis>`` of every GP term into the posterior (:mod:`heli_uq.output.gp`)."""
    import xarray as xr

    for axis, (torque, points, fitted) in gp_torques(problem, samples).items():
        dim = f"gp_pair_{axis}"
        coords = {dim: np.arange(torque.shape[-1]), f"{dim}_fitted": (dim, fitted),
                  **{f"{dim}_{k}": (dim, np.asarray(v)) for k, v in points.items()}}  # fmt: skip
        idata.posterior[f"gp_torque_{axis}"] = xr.DataArray(
            torque, dims=("chain", "draw", dim),
            coords={"chain": idata.posterior["chain"], "draw": idata.posterior["draw"], **coords},
            attrs={"units": "N m", "long_name": f"GP torque on {axis} at its voltage pairs "
                                                 "(u_theta, u_psi); fitted: the training window "
                                                 "holds the pair"})  # fmt: skip


def _add_network_torques(idata: az.InferenceData, problem, samples: dict) -> None:
    """``nn_torque_<axis>`` of every neural term into the posterior (module docstring)."""
    import xarray as xr

    for key, (torque, points) in network_torques(problem, samples).items():
        dim = f"nn_point_{key}"
        axis, unseen = key.removesuffix(UNSEEN), key.endswith(UNSEEN)
        where = "voltage pairs the training window never holds" if unseen else "training window's inputs"
        coords = {dim: np.arange(torque.shape[-1]),
                  **{f"{dim}_{k}": (dim, np.asarray(v)) for k, v in points.items()}}  # fmt: skip
        idata.posterior[f"nn_torque_{key}"] = xr.DataArray(
            torque, dims=("chain", "draw", dim),
            coords={"chain": idata.posterior["chain"], "draw": idata.posterior["draw"], **coords},
            attrs={"units": "N m", "long_name": f"network torque on {axis} at the {where} "
                                                 f"({', '.join(points)})"})  # fmt: skip


#: NetCDF encoding of every numeric variable: zlib after the byte-shuffle filter, which
#: groups the bytes of equal significance (a third smaller than zlib alone on the
#: predictive draws).
COMPRESSION = {"zlib": True, "complevel": 4, "shuffle": True}


def _write_groups(idata: az.InferenceData, path: str) -> None:
    """arviz's NetCDF layout (one HDF5 group per InferenceData group), compressed with
    :data:`COMPRESSION`."""
    import xarray as xr

    mode = "w"
    if idata.attrs:
        xr.Dataset(attrs=idata.attrs).to_netcdf(path, mode=mode, engine="h5netcdf")
        mode = "a"
    for group in idata.groups():
        data = getattr(idata, group)
        encoding = {name: dict(COMPRESSION) for name, var in data.variables.items()
                    if var.dtype.kind in "fiub" and var.ndim > 0}  # fmt: skip
        data.to_netcdf(path, mode=mode, group=group, engine="h5netcdf", encoding=encoding)
        mode = "a"


def save_netcdf(idata: az.InferenceData, path) -> None:
    """Write ``idata`` to NetCDF atomically (temporary file + rename), compressed
    (:data:`COMPRESSION`); read it back with :func:`arviz.from_netcdf` or
    :func:`load_posterior`."""
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(fd)
    try:
        _write_groups(idata, tmp)
        publish(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def load_posterior(path):
    """``(idata, model)`` of a ``posterior.nc``: the model is rebuilt from its description.

    Raises
    ------
    DataFormatError
        Unreadable file, or no model description in its attributes.
    """
    path = pathlib.Path(path)
    try:
        idata = az.from_netcdf(path)
        attrs = idata.posterior.attrs
    except Exception as exc:  # noqa: BLE001  (any unreadable file: one clear message)
        raise DataFormatError(f"{path}: not a readable posterior.nc ({type(exc).__name__})") from None
    if "model" not in attrs:
        raise DataFormatError(f"{path}: the posterior has no model description (written by an "
                              "older heli_uq); sample it again")  # fmt: skip
    return idata, model_from_description(attrs["model"], where=f"{path} (model attribute)")
