"""Posterior sampling: numpyro NUTS and emcee on the one model, saved in chunks, resumable.

Both samplers start from a multi-start MAP (:mod:`heli_uq.optimize`) so chains do not
start in the regime where the model flies off; NUTS also uses the Laplace covariance
there as its dense inverse mass matrix, and by default keeps adapting it in warm-up
(see ``adapt_mass_matrix`` of :func:`run_nuts`).

Chunks: after warm-up the draws are produced ``chunk`` at a time; each chunk is written
atomically to ``DIR/chunks/`` with the sampler state, so Ctrl-C or a crash loses at most
one chunk and ``resume=True`` continues from the last saved state with the same seed
stream (same seed, same draws).
"""

from __future__ import annotations

import dataclasses
import pathlib
import pickle
import time

import jax
import jax.numpy as jnp
import numpy as np
from numpyro.infer import MCMC, NUTS, init_to_value

from heli_uq.errors import ParameterError
from heli_uq.io import atomic_write_bytes
from heli_uq.model import Problem, heli_model
from heli_uq.optimize import LogDensity, find_map, laplace, log_density_setup, map_starts

__all__ = ["SamplerRun", "prepare_start", "run_nuts"]

NUTS_EXTRA_FIELDS = ("diverging", "num_steps", "energy", "accept_prob", "potential_energy")


@dataclasses.dataclass
class SamplerRun:
    """Raw result of a sampler: constrained draws and per-draw statistics.

    ``samples``: dict of arrays (chain, draw, ...); ``stats``: dict of arrays (chain, draw);
    ``info``: sampler facts (wall time, MAP value, step size, ...).
    """

    samples: dict
    stats: dict
    info: dict


@dataclasses.dataclass(frozen=True, eq=False)
class Start:
    """A MAP start: the log density, the MAP point and its Laplace covariance."""

    density: LogDensity
    x_map: np.ndarray
    map_value: float
    covariance: np.ndarray
    map_seconds: float
    #: Convergence of the MAP: ``max |grad|`` and Newton decrement at ``x_map``.
    map_grad_max: float = float("nan")
    map_decrement: float = float("nan")


def prepare_start(problem: Problem, *, n_starts: int = 4, seed: int = 0,
                  map_maxiter: int = 200) -> Start:  # fmt: skip
    """Multi-start MAP and Laplace covariance (the shared start of NUTS and emcee).

    ``map_maxiter``: L-BFGS steps per start before the Newton polish of
    :func:`~heli_uq.optimize.find_map` (0: Newton only, which saves compiling L-BFGS).
    """
    t0 = time.perf_counter()
    density = log_density_setup(problem, seed=seed)
    result = find_map(density, map_starts(problem, density, n_starts, seed), maxiter=map_maxiter)
    if not np.isfinite(result.value):
        raise ParameterError(
            "no MAP start gave a finite log density: the model diverges from every start "
            "(check the data window and the priors)"
        )
    _, cov = laplace(density, result.x)
    return Start(density, result.x, result.value, cov, time.perf_counter() - t0,
                 result.grad_max, result.newton_decrement)


def _chunk_dir(out: pathlib.Path) -> pathlib.Path:
    d = out / "chunks"
    d.mkdir(parents=True, exist_ok=True)
    return d


def _save_chunk(chunks: pathlib.Path, index: int, samples, stats, state):
    arrays = {f"s:{k}": np.asarray(v) for k, v in samples.items()}
    arrays.update({f"t:{k}": np.asarray(v) for k, v in stats.items()})
    import io

    buf = io.BytesIO()
    np.savez(buf, **arrays)
    atomic_write_bytes(chunks / f"chunk_{index:05d}.npz", buf.getvalue())
    atomic_write_bytes(chunks / "state.pkl", pickle.dumps((index, jax.device_get(state))))


def _load_chunks(chunks: pathlib.Path):
    files = sorted(chunks.glob("chunk_*.npz"))
    samples, stats = {}, {}
    for f in files:
        with np.load(f) as z:
            for key in z.files:
                kind, name = key.split(":", 1)
                target = samples if kind == "s" else stats
                target.setdefault(name, []).append(z[key])
    cat = {k: np.concatenate(v, axis=1) for k, v in samples.items()}
    return cat, {k: np.concatenate(v, axis=1) for k, v in stats.items()}, len(files)


def run_nuts(problem: Problem, out_dir, *, chains: int = 4, warmup: int = 1000,
             draws: int = 1000, seed: int = 0, chunk: int = 250, resume: bool = False,
             progress: bool = True, max_tree_depth: int = 8, target_accept: float = 0.85,
             adapt_mass_matrix: bool = True, start: Start | None = None) -> SamplerRun:  # fmt: skip
    """NUTS with the Laplace covariance at the MAP as dense inverse mass matrix.

    Parameters
    ----------
    problem : Problem
    out_dir : path
        ``out_dir/chunks`` receives the draws as they are made.
    chains, warmup, draws : int
        Independent chains; warm-up and kept iterations per chain.
    chunk : int
        Draws per saved chunk.
    resume : bool
        Continue from ``out_dir/chunks`` (same settings) instead of starting again.
    adapt_mass_matrix : bool
        Keep adapting the (Laplace-initialised) dense mass matrix during warm-up.  numpyro
        shrinks its dense estimate towards ``1e-3 * I`` in *absolute* units, which adds
        ~1e-4 of variance to the stiffest posterior direction (variance ~1e-9: the pitch
        gain vs. gravity-ratio balance), so the adapted step size collapses ~100-fold and
        NUTS runs at the tree-depth limit (255 leapfrog steps per draw).  ``False`` keeps
        the Laplace matrix: on 5 s synthetic SBC records (noise 0.01-0.15 rad) step ~0.17, ~26
        steps, 0-1 divergences per 300 draws; on the 4 s, 3 mrad test record the curved
        ridge then gives step ~0.05, ~100-150 steps and divergences, where the collapsed
        step of ``True`` has none.  ``True`` stays the default as the conservative choice;
        the step size is adapted either way.
    """
    for name, value in (("chains", chains), ("warmup", warmup), ("draws", draws),
                        ("chunk", chunk)):  # fmt: skip
        if int(value) <= 0:
            raise ParameterError(f"--{name}: expected a positive integer, found {value}")
    out = pathlib.Path(out_dir)
    chunks = _chunk_dir(out)
    t_start = time.perf_counter()
    state_file = chunks / "state.pkl"
    if resume and state_file.exists():
        samples, stats, done = _load_chunks(chunks)
        with open(state_file, "rb") as fh:
            _, state = pickle.load(fh)
        with open(chunks / "start.pkl", "rb") as fh:
            info = pickle.load(fh)
        start = None
    else:
        for f in chunks.glob("chunk_*.npz"):
            f.unlink()
        samples, stats, done, state = {}, {}, 0, None
        start = prepare_start(problem, seed=seed) if start is None else start
        info = {"map_value": float(start.map_value), "map_seconds": float(start.map_seconds),
                "map_grad_max": float(start.map_grad_max),
                "map_decrement": float(start.map_decrement),
                "x_map": start.x_map, "inverse_mass_matrix": start.covariance}  # fmt: skip
        atomic_write_bytes(chunks / "start.pkl", pickle.dumps(info))
    density = start.density if start is not None else log_density_setup(problem, seed=seed)
    init_values = density.constrain(density.unravel(jnp.asarray(info["x_map"])))
    init_values = {k: v for k, v in init_values.items() if k in density.unravel(density.x_init)}
    kernel = NUTS(heli_model, dense_mass=True, inverse_mass_matrix=jnp.asarray(
        info["inverse_mass_matrix"]), init_strategy=init_to_value(values=init_values),
        max_tree_depth=max_tree_depth, target_accept_prob=target_accept,
        adapt_mass_matrix=adapt_mass_matrix)  # fmt: skip
    n_dev = jax.local_device_count()
    method = "parallel" if n_dev >= min(chains, 2) and chains > 1 else "sequential"
    n_chunks = -(-draws // chunk)
    mcmc = MCMC(kernel, num_warmup=warmup, num_samples=chunk, num_chains=chains,
                chain_method=method, progress_bar=progress)  # fmt: skip
    key = jax.random.PRNGKey(seed)
    warm_seconds = 0.0
    if state is None:
        t0 = time.perf_counter()
        mcmc.warmup(key, problem, **density.model_kwargs, collect_warmup=False,
                    extra_fields=NUTS_EXTRA_FIELDS)  # fmt: skip
        warm_seconds = time.perf_counter() - t0
        state = mcmc.post_warmup_state
    for index in range(done, n_chunks):
        mcmc.post_warmup_state = state
        mcmc.run(state.rng_key, problem, **density.model_kwargs, extra_fields=NUTS_EXTRA_FIELDS)
        state = mcmc.last_state
        new = {k: np.asarray(v) for k, v in mcmc.get_samples(group_by_chain=True).items()}
        extra = {k: np.asarray(v) for k, v in mcmc.get_extra_fields(group_by_chain=True).items()}
        _save_chunk(chunks, index, new, extra, state)
        for k, v in new.items():
            samples[k] = np.concatenate([samples[k], v], axis=1) if k in samples else v
        for k, v in extra.items():
            stats[k] = np.concatenate([stats[k], v], axis=1) if k in stats else v
    samples = {k: v[:, :draws] for k, v in samples.items()}
    stats = {k: v[:, :draws] for k, v in stats.items()}
    adapt = state.adapt_state
    info = dict(info, sampler="nuts", chains=chains, warmup=warmup, draws=draws, seed=seed,
                chain_method=method, warmup_seconds=warm_seconds,
                step_size=np.asarray(adapt.step_size).tolist(),
                max_tree_depth=max_tree_depth, wall_seconds=time.perf_counter() - t_start)
    return SamplerRun(samples=samples, stats=stats, info=info)
