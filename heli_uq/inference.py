"""Posterior sampling: numpyro NUTS and emcee on the one model, saved in chunks, resumable.

Both samplers start from a multi-start MAP (:mod:`heli_uq.optimize`) so chains do not
start in the regime where the model flies off.  NUTS moves in coordinates whitened by
the Laplace covariance at the MAP and adapts a dense mass matrix there (see
:func:`run_nuts` for why this and not the Laplace matrix as initial mass matrix).

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
from numpyro.infer import MCMC, NUTS

from heli_uq.errors import ParameterError
from heli_uq.io import atomic_write_bytes
from heli_uq.model import Problem
from heli_uq.optimize import (
    LogDensity, constrain_draws, find_map, laplace, log_density_setup, map_starts,
)

__all__ = ["SamplerRun", "prepare_start", "run_nuts"]

NUTS_EXTRA_FIELDS = ("diverging", "num_steps", "energy", "accept_prob", "potential_energy")
#: Default target acceptance of the step-size adaptation.  On the full rig record
#: (4 x (1000 + 1000), iid errors) 0.9 gave 1 divergence in 4000 draws and 15.8 leapfrog
#: steps per draw, 0.95 none and 17.0 steps (+8 % gradients).
TARGET_ACCEPT = 0.95
#: Chains start at ``w ~ N(0, INIT_SPREAD^2 I)`` in whitened coordinates (1: a Laplace draw);
#: a start where the model fails is redrawn up to MAX_INIT_ROUNDS times, then set to the MAP.
INIT_SPREAD = 1.0
MAX_INIT_ROUNDS = 10


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


def _whitening(start_info: dict) -> tuple[np.ndarray, np.ndarray]:
    """``(x_map, L)`` with ``L L^T`` the Laplace covariance: ``x = x_map + L w``."""
    cov = np.asarray(start_info["laplace_covariance"], dtype=float)
    return np.asarray(start_info["x_map"], dtype=float), np.linalg.cholesky(0.5 * (cov + cov.T))


def _initial_positions(potential, chains: int, dim: int, seed: int) -> np.ndarray:
    """One start per chain in whitened coordinates: a draw of the Laplace approximation
    (``w ~ N(0, INIT_SPREAD^2 I)``), redrawn where the model fails, else the MAP (w = 0)."""
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(1,)))
    w = INIT_SPREAD * rng.standard_normal((chains, dim))
    batched = jax.jit(jax.vmap(potential))
    for _ in range(MAX_INIT_ROUNDS):
        bad = ~np.isfinite(np.asarray(batched(jnp.asarray(w))))
        if not bad.any():
            return w
        w[bad] = INIT_SPREAD * rng.standard_normal((int(bad.sum()), dim))
    w[bad] = 0.0
    return w


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
        Continue from ``out_dir/chunks`` (same settings) instead of starting again.
    target_accept : float
        Target mean acceptance probability of step-size adaptation.
    adapt_mass_matrix : bool
        Adapt the dense mass matrix in whitened coordinates during warm-up (``False``:
        keep the identity, i.e. the Laplace covariance).
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
                "x_map": start.x_map, "laplace_covariance": start.covariance}  # fmt: skip
        atomic_write_bytes(chunks / "start.pkl", pickle.dumps(info))
    density = start.density if start is not None else log_density_setup(problem, seed=seed)
    x_map, lower = _whitening(info)
    x_map_j, lower_j = jnp.asarray(x_map), jnp.asarray(lower)

    def potential(w):
        return density.potential(x_map_j + lower_j @ w)

    kernel = NUTS(potential_fn=potential, dense_mass=True, max_tree_depth=max_tree_depth,
                  target_accept_prob=target_accept, adapt_mass_matrix=adapt_mass_matrix)
    n_dev = jax.local_device_count()
    method = "parallel" if n_dev >= chains and chains > 1 else "sequential"
    n_chunks = -(-draws // chunk)
    chunk = -(-draws // n_chunks)  # equal chunks: no draws made only to be cut off
    mcmc = MCMC(kernel, num_warmup=warmup, num_samples=chunk, num_chains=chains,
                chain_method=method, progress_bar=progress)  # fmt: skip
    key = jax.random.PRNGKey(seed)
    warm_seconds = 0.0
    if state is None:
        t0 = time.perf_counter()
        w0 = _initial_positions(potential, chains, x_map.size, seed)
        mcmc.warmup(key, init_params=jnp.asarray(w0 if chains > 1 else w0[0]),
                    collect_warmup=False, extra_fields=NUTS_EXTRA_FIELDS)  # fmt: skip
        state = jax.block_until_ready(mcmc.post_warmup_state)
        warm_seconds = time.perf_counter() - t0
    for index in range(done, n_chunks):
        mcmc.post_warmup_state = state
        # init_params: a resumed run has a fresh kernel, which numpyro initialises from
        # them (the loaded state, incl. its adaptation, is what is then continued).
        mcmc.run(state.rng_key, init_params=state.z, extra_fields=NUTS_EXTRA_FIELDS)
        state = mcmc.last_state
        w = np.asarray(mcmc.get_samples(group_by_chain=True)).reshape(chains, chunk, -1)
        flat = constrain_draws(density, (x_map + w @ lower.T).reshape(-1, x_map.size))
        new = {k: v.reshape((chains, chunk) + v.shape[1:]) for k, v in flat.items()}
        extra = {k: np.asarray(v).reshape(chains, chunk)
                 for k, v in mcmc.get_extra_fields(group_by_chain=True).items()}
        _save_chunk(chunks, index, new, extra, state)
        for k, v in new.items():
            samples[k] = np.concatenate([samples[k], v], axis=1) if k in samples else v
        for k, v in extra.items():
            stats[k] = np.concatenate([stats[k], v], axis=1) if k in stats else v
    samples = {k: v[:, :draws] for k, v in samples.items()}
    stats = {k: v[:, :draws] for k, v in stats.items()}
    adapt = state.adapt_state
    info = dict(info, sampler="nuts", chains=chains, warmup=warmup, draws=draws, seed=seed,
                chain_method=method, warmup_seconds=warm_seconds, coordinates="laplace_whitened",
                step_size=np.asarray(adapt.step_size).tolist(), target_accept=target_accept,
                max_tree_depth=max_tree_depth, wall_seconds=time.perf_counter() - t_start)
    return SamplerRun(samples=samples, stats=stats, info=info)
