"""NUTS (numpyro) in coordinates whitened by the Laplace approximation, saved in chunks.

The sampler starts from the multi-start MAP (:func:`heli_uq.inference.prepare_start`),
so chains do not start in the regime where the model flies off.  Draws are produced
``chunk`` at a time after warm-up and written with the sampler state
(:class:`~heli_uq.inference.checkpoint.Checkpoint`), so ``resume=True`` continues an
interrupted run with the same seed stream (same seed, same draws).
"""

from __future__ import annotations

import dataclasses
import pathlib
import time

import jax
import jax.numpy as jnp
import numpy as np
from numpyro.infer import MCMC, NUTS

from heli_uq.errors import ParameterError
from heli_uq.inference.checkpoint import Checkpoint
from heli_uq.inference.density import constrain_draws, log_density_setup
from heli_uq.inference.manifest import run_manifest
from heli_uq.inference.start import Start, initial_draws, prepare_start, whitening
from heli_uq.probability.problem import Problem

__all__ = ["SamplerRun", "run_nuts", "TARGET_ACCEPT"]

NUTS_EXTRA_FIELDS = ("diverging", "num_steps", "energy", "accept_prob", "potential_energy")
#: Default target acceptance of the step-size adaptation.  On the full rig record
#: (4 x (1000 + 1000), iid errors) 0.9 gave 1 divergence in 4000 draws and 15.8 leapfrog
#: steps per draw, 0.95 none and 17.0 steps (+8 % gradients).
TARGET_ACCEPT = 0.95
CHUNK_DIR = "chunks"


@dataclasses.dataclass
class SamplerRun:
    """Raw result of a sampler.

    ``samples``: dict of constrained draws (chain, draw, ...) by site name (physical
    parameters, initial state, error model, coordinates ``z``); ``stats``: dict of per-draw
    statistics (chain, draw); ``info``: sampler facts (wall time, MAP value, step size...);
    ``problem``: the problem sampled (with the substeps the MAP chose).
    """

    samples: dict
    stats: dict
    info: dict
    problem: Problem


def _start_info(start: Start) -> dict:
    return dict(start.info(), x_map=np.asarray(start.x_map), covariance=np.asarray(start.covariance))


def run_nuts(problem: Problem, out_dir, *, chains: int = 4, warmup: int = 1000,
             draws: int = 1000, seed: int = 0, chunk: int = 250, resume: bool = False,
             progress: bool = True, max_tree_depth: int = 8,
             target_accept: float = TARGET_ACCEPT, adapt_mass_matrix: bool = True,
             start: Start | None = None) -> SamplerRun:  # fmt: skip
    """NUTS in coordinates whitened by the Laplace approximation at the MAP.

    NUTS moves in ``w`` with ``x = x_map + L w`` (``x``: numpyro's unconstrained vector,
    ``L L^T``: the Laplace covariance), where the posterior is close to ``N(0, I)``; the
    Jacobian of this map is constant, so the target is unchanged.  Warm-up adapts the
    step size and a dense mass matrix *in w*, starting from the identity.

    Why whiten instead of passing the Laplace covariance as the initial mass matrix:
    numpyro regularises every dense estimate towards ``1e-3 * I`` in absolute units of
    the sampled coordinates.  In ``x`` that adds ~1e-4 of variance to the stiffest
    posterior direction (variance ~1e-9, the pitch gain vs. gravity-ratio balance), so the
    step size collapsed ~100-fold and every draw hit the tree-depth limit; in ``w`` every
    direction has variance ~1 and the same regularisation is harmless.

    Parameters
    ----------
    problem : Problem
    out_dir : path
        ``out_dir/chunks`` receives the draws as they are made.
    chains, warmup, draws : int
        Independent chains; warm-up and kept iterations per chain.  Chains start from
        independent draws of the Laplace approximation.  They run in parallel when JAX
        has at least ``chains`` devices (the CLI sets ``numpyro.set_host_device_count``).
    chunk : int
        Draws per saved chunk.
    resume : bool
        Continue from ``out_dir/chunks`` (same settings, else an error) instead of
        starting again.
    target_accept : float
        Target mean acceptance probability of step-size adaptation.
    adapt_mass_matrix : bool
        Adapt the dense mass matrix in whitened coordinates during warm-up (``False``:
        keep the identity, i.e. the Laplace covariance).
    start : Start, optional
        The MAP start; computed if not given.

    Raises
    ------
    ParameterError
        Invalid options, or a resume under different settings.
    """
    for name, value in (("chains", chains), ("warmup", warmup), ("draws", draws),
                        ("chunk", chunk)):  # fmt: skip
        if isinstance(value, bool) or int(value) != value or int(value) <= 0:
            raise ParameterError(f"{name}: expected a positive integer, found {value!r}")
    if not 0.0 < target_accept < 1.0:
        raise ParameterError(f"target_accept: expected a number in (0, 1), found {target_accept!r}")
    t_start = time.perf_counter()
    checkpoint = Checkpoint(pathlib.Path(out_dir) / CHUNK_DIR)
    manifest = run_manifest(problem, {
        "sampler": "nuts", "chains": chains, "warmup": warmup, "draws": draws, "chunk": chunk,
        "seed": seed, "max_tree_depth": max_tree_depth, "target_accept": target_accept,
        "adapt_mass_matrix": adapt_mass_matrix})  # fmt: skip
    info = checkpoint.resume_info(manifest) if resume else None
    records = checkpoint.load("nuts") if info is not None else []
    if info is None:
        start = prepare_start(problem, seed=seed) if start is None else start
        info = _start_info(start)
        checkpoint.start_new(info, manifest)
        density = start.density
    else:
        density = log_density_setup(problem.with_substeps(info["substeps"]), seed=seed)
    problem = density.problem
    x_map, lower = whitening(info)
    x_map_j, lower_j = jnp.asarray(x_map), jnp.asarray(lower)

    def potential(w):
        return density.potential(x_map_j + lower_j @ w)

    kernel = NUTS(potential_fn=potential, dense_mass=True, max_tree_depth=max_tree_depth,
                  target_accept_prob=target_accept, adapt_mass_matrix=adapt_mass_matrix)
    method = "parallel" if jax.local_device_count() >= chains and chains > 1 else "sequential"
    n_chunks = -(-draws // chunk)
    chunk = -(-draws // n_chunks)  # equal chunks: no draws made only to be cut off
    mcmc = MCMC(kernel, num_warmup=warmup, num_samples=chunk, num_chains=chains,
                chain_method=method, progress_bar=progress)  # fmt: skip
    warm_seconds = 0.0
    if records:
        state = records[-1]["state"]
    else:
        t0 = time.perf_counter()
        rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(1,)))
        batched = jax.jit(jax.vmap(potential))
        w0 = initial_draws(lambda w: batched(jnp.asarray(w)), chains, x_map.size, rng,
                           on_failure="map")  # fmt: skip
        mcmc.warmup(jax.random.PRNGKey(seed), init_params=jnp.asarray(w0 if chains > 1 else w0[0]),
                    collect_warmup=False, extra_fields=NUTS_EXTRA_FIELDS)  # fmt: skip
        state = jax.block_until_ready(mcmc.post_warmup_state)
        warm_seconds = time.perf_counter() - t0
    for index in range(len(records), n_chunks):
        mcmc.post_warmup_state = state
        # init_params: a resumed run has a fresh kernel, which numpyro initialises from
        # them (the loaded state, incl. its adaptation, is what is then continued).
        mcmc.run(state.rng_key, init_params=state.z, extra_fields=NUTS_EXTRA_FIELDS)
        state = mcmc.last_state
        w = np.asarray(mcmc.get_samples(group_by_chain=True)).reshape(chains, chunk, -1)
        extra = {k: np.asarray(v).reshape(chains, chunk)
                 for k, v in mcmc.get_extra_fields(group_by_chain=True).items()}  # fmt: skip
        record = {"x": x_map + w @ lower.T, "stats": extra, "state": state}
        checkpoint.save("nuts", index, record)
        records.append(record)
    x = np.concatenate([r["x"] for r in records], axis=1)[:, :draws]
    flat = constrain_draws(density, x.reshape(-1, x.shape[-1]))
    samples = {k: v.reshape((chains, draws) + v.shape[1:]) for k, v in flat.items()}
    stats = {k: np.concatenate([r["stats"][k] for r in records], axis=1)[:, :draws]
             for k in records[0]["stats"]}  # fmt: skip
    out_info = {k: v for k, v in info.items() if k not in ("x_map", "covariance")}
    out_info.update(sampler="nuts", chains=chains, warmup=warmup, draws=draws, seed=seed,
                    chain_method=method, warmup_seconds=warm_seconds,
                    coordinates="laplace_whitened",
                    step_size=np.asarray(state.adapt_state.step_size).tolist(),
                    target_accept=target_accept, max_tree_depth=max_tree_depth,
                    wall_seconds=time.perf_counter() - t_start)  # fmt: skip
    return SamplerRun(samples=samples, stats=stats, info=out_info, problem=problem)
