"""emcee (affine-invariant ensemble sampler) on the same log density as NUTS.

The target is ``-potential(x)`` of :func:`heli_uq.optimize.log_density_setup`, i.e.
numpyro's flat *unconstrained* vector of :func:`heli_uq.model.heli_model`, evaluated for
all walkers at once (``jax.jit(jax.vmap(...))`` with emcee's ``vectorize=True``).  A
non-finite value (failed ODE solve, overflow) becomes ``-inf``: a rejected proposal.

Independent ensembles.  The walkers of one ensemble are not independent chains (every
move uses the other walkers), so R-hat across walkers is meaningless.  ``ensembles``
independent ensembles (own seed, own initial scatter around the MAP) are run one after
another, and each ensemble is one "chain" of the returned :class:`SamplerRun`: its
draws are the kept steps of all walkers, interleaved step by step (``draw = step *
walkers + walker``).  R-hat and ESS computed by arviz on these chains are approximate
(the draws of one step are correlated across walkers, and consecutive draws of one
walker are ``walkers`` apart).  ``info`` also reports emcee's own diagnostics per
ensemble: integrated autocorrelation time ``tau`` per unconstrained coordinate, the
effective sample size ``ess_emcee`` and the mean acceptance fraction.

Chunks: every ``chunk`` steps the new part of the chain and the sampler state (walker
positions, their log densities, the random state) are written atomically to
``DIR/chunks_emcee/``; Ctrl-C or a crash loses at most one chunk, and ``resume=True``
continues every ensemble from its last saved state (same seed, same draws, also for a
larger ``steps`` than the interrupted run).
"""

from __future__ import annotations

import functools
import pathlib
import pickle
import time

import emcee
import jax
import jax.numpy as jnp
import numpy as np

from heli_uq.errors import ParameterError
from heli_uq.inference import SamplerRun, Start, prepare_start
from heli_uq.io import atomic_write_bytes
from heli_uq.model import Problem
from heli_uq.optimize import LogDensity, batched_constrain, constrain_draws, log_density_setup

__all__ = ["run_emcee", "INIT_SCALE", "TAU_FACTOR"]

#: Initial walkers: MAP + INIT_SCALE * N(0, Laplace covariance).
INIT_SCALE = 0.1
#: Rounds of redrawing initial walkers whose log density is not finite.
MAX_INIT_ROUNDS = 100
#: emcee's rule: the chain must be longer than TAU_FACTOR integrated autocorrelation times.
TAU_FACTOR = 50
#: Mean acceptance fraction below which walkers are reported as (nearly) stuck.
MIN_ACCEPTANCE = 0.1
CHUNK_DIR = "chunks_emcee"
START_FILE = "start.pkl"
#: Settings that must match between an interrupted run and its resumption.
RESUME_KEYS = ("walkers", "dim", "seed")

#: Compiled batched functions kept (per underlying function of a density).
JIT_CACHE_SIZE = 8


@functools.lru_cache(maxsize=JIT_CACHE_SIZE)
def _batched_log_post(potential):
    return jax.jit(jax.vmap(lambda x: -potential(x)))


def _batched(density: LogDensity):
    """Jitted, vmapped ``(log posterior, constrain)`` of ``density``: ``x (n, d) ->``
    ``log p (n,)`` and ``x (n, d) ->`` dict of constrained sites (leading axis n).
    Cached, so repeated runs on one density compile once."""
    return (_batched_log_post(density.potential),
            batched_constrain(density))  # fmt: skip


def _log_prob_fn(density: LogDensity):
    """emcee's vectorised target: ``x (n, d) -> log p (n,)`` with non-finite -> ``-inf``."""
    log_post, _ = _batched(density)

    def log_prob(x):
        lp = np.asarray(log_post(jnp.asarray(x)), dtype=float)
        return np.where(np.isfinite(lp), lp, -np.inf)

    return log_prob


def coordinate_names(density: LogDensity) -> list[str]:
    """Names of the entries of the flat unconstrained vector (``sigma[0]``, ``z[3]``, ...)."""
    leaves, _ = jax.tree_util.tree_flatten_with_path(density.unravel(density.x_init))
    names = []
    for path, leaf in leaves:
        base = "".join(str(getattr(k, "key", k)) for k in path)
        size = int(np.size(leaf))
        names += [base] if np.ndim(leaf) == 0 else [f"{base}[{i}]" for i in range(size)]
    return names


def _positive_int(name: str, value) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value <= 0:
        raise ParameterError(f"--{name}: expected a positive integer, found {value!r}")
    return int(value)


def _check_options(ensembles, walkers, steps, burn, thin, chunk) -> int:
    """Validate the options and return ``burn`` (``walkers`` is checked against the
    dimension once the density is known, :func:`_check_walkers`)."""
    for name, value in (("ensembles", ensembles), ("steps", steps), ("thin", thin),
                        ("chunk", chunk)):  # fmt: skip
        _positive_int(name, value)
    if walkers is not None:
        _positive_int("walkers", walkers)
    burn = steps // 2 if burn is None else burn
    if isinstance(burn, bool) or not isinstance(burn, (int, np.integer)) or not 0 <= burn < steps:
        raise ParameterError(
            f"--burn: expected an integer in [0, steps) = [0, {steps}), found {burn!r}"
        )
    return int(burn)


def _check_walkers(walkers, dim: int) -> int:
    walkers = 2 * dim + 2 if walkers is None else int(walkers)
    if walkers < 2 * dim:
        raise ParameterError(
            f"--walkers: expected at least 2 * dimension = {2 * dim} walkers for the "
            f"{dim}-dimensional posterior, found {walkers}"
        )
    return walkers


def _ensemble_seeds(seed: int, ensemble: int):
    """(Generator for the initial scatter, emcee random state) of one ensemble.

    Derived with :class:`numpy.random.SeedSequence` from ``(seed, ensemble)``, so an
    ensemble's draws do not depend on how many ensembles are run.
    """
    scatter, moves = np.random.SeedSequence(seed, spawn_key=(ensemble,)).spawn(2)
    rng = np.random.default_rng(scatter)
    random_state = np.random.RandomState(np.random.MT19937(moves)).get_state()
    return rng, random_state


def _initial_walkers(log_prob, x_map, covariance, walkers: int, rng):
    """Walkers around the MAP (Laplace covariance scaled by INIT_SCALE), finite log p."""
    x_map = np.asarray(x_map, dtype=float)
    cov = INIT_SCALE**2 * np.asarray(covariance, dtype=float)
    coords = np.empty((walkers, x_map.size))
    bad = np.arange(walkers)
    for _ in range(MAX_INIT_ROUNDS):
        coords[bad] = rng.multivariate_normal(x_map, cov, size=bad.size, method="eigh")
        lp = log_prob(coords)  # all walkers: one batch shape, one compilation
        bad = np.flatnonzero(~np.isfinite(lp))
        if bad.size == 0:
            return coords, lp
    raise ParameterError(
        f"{bad.size} of {walkers} initial walkers still have a non-finite log density after "
        f"{MAX_INIT_ROUNDS} redraws around the MAP (the model diverges near the MAP)"
    )


def _chunk_file(chunks: pathlib.Path, ensemble: int, index: int) -> pathlib.Path:
    return chunks / f"ensemble_{ensemble:03d}_chunk_{index:05d}.pkl"


def _save_chunk(chunks: pathlib.Path, ensemble: int, index: int, record: dict):
    """Write one chunk (new steps, acceptance counts, final sampler state) atomically."""
    atomic_write_bytes(_chunk_file(chunks, ensemble, index), pickle.dumps(record))


def _load_ensemble(chunks: pathlib.Path, ensemble: int):
    """Saved chunks of one ensemble, in order: (list of records)."""
    records = []
    while (f := _chunk_file(chunks, ensemble, len(records))).exists():
        with open(f, "rb") as fh:
            records.append(pickle.load(fh))
    return records


def _run_ensemble(density, start_info, ensemble, *, walkers, steps, chunk, seed, chunks,
                  progress, n_ensembles):  # fmt: skip
    """Run (or continue) one ensemble to ``steps`` steps, saving every ``chunk`` steps.

    Returns
    -------
    chain : ndarray, shape (steps, walkers, dim)
    log_prob : ndarray, shape (steps, walkers)
    accepted : ndarray, shape (walkers,)
        Accepted proposals per walker over the ``steps`` steps.
    """
    log_prob = _log_prob_fn(density)
    records = _load_ensemble(chunks, ensemble)
    done = sum(r["chain"].shape[0] for r in records)
    if records:
        last = records[-1]
        state = emcee.State(last["coords"], log_prob=last["log_prob_last"],
                            random_state=last["random_state"])  # fmt: skip
    else:
        rng, random_state = _ensemble_seeds(seed, ensemble)
        coords, lp = _initial_walkers(log_prob, start_info["x_map"], start_info["covariance"],
                                      walkers, rng)  # fmt: skip
        state = emcee.State(coords, log_prob=lp, random_state=random_state)
    sampler = emcee.EnsembleSampler(walkers, density.dim, log_prob, vectorize=True)
    desc = f"emcee ensemble {ensemble + 1}/{n_ensembles}"
    while done < steps:
        n = min(chunk, steps - done)
        sampler.reset()
        bar = {"desc": f"{desc}, steps {done}-{done + n}"}
        state = sampler.run_mcmc(state, n, progress=progress, progress_kwargs=bar)
        record = {"chain": sampler.get_chain(), "log_prob": sampler.get_log_prob(),
                  "accepted": np.asarray(sampler.backend.accepted).copy(),
                  "coords": np.asarray(state.coords), "log_prob_last": np.asarray(state.log_prob),
                  "random_state": state.random_state}  # fmt: skip
        _save_chunk(chunks, ensemble, len(records), record)
        records.append(record)
        done += n
    chain = np.concatenate([r["chain"] for r in records])[:steps]
    lp = np.concatenate([r["log_prob"] for r in records])[:steps]
    # Accepted moves in the first ``steps`` steps (pro rata in a chunk cut by a resume
    # with fewer steps than were saved).
    used, accepted = 0, np.zeros(walkers)
    for r in records:
        if used + r["chain"].shape[0] > steps:
            accepted += r["accepted"] * (steps - used) / r["chain"].shape[0]
            break
        accepted += r["accepted"]
        used += r["chain"].shape[0]
    return chain, lp, accepted


def _autocorrelation(chain: np.ndarray, kept_draws: int, ensemble: int):
    """tau per coordinate, ESS and warnings of one ensemble's post-burn chain.

    ``chain``: (post-burn steps, walkers, dim), unthinned, so ``tau`` is in steps.
    ``ess = steps * walkers / max(tau)``, at most the number of kept draws.
    """
    n, walkers, _ = chain.shape
    try:
        with np.errstate(invalid="ignore", divide="ignore"):  # a constant coordinate
            tau = emcee.autocorr.integrated_time(chain)
    except emcee.autocorr.AutocorrError as err:  # too short: the estimate, without logging
        tau = err.tau
    tau = np.asarray(tau, dtype=float)
    warnings = []
    tau_max = float(np.max(tau)) if np.all(np.isfinite(tau)) else np.inf
    if not np.isfinite(tau_max):
        warnings.append(f"ensemble {ensemble}: autocorrelation time is not finite "
                        "(a coordinate does not move)")  # fmt: skip
    elif n < TAU_FACTOR * tau_max:
        warnings.append(
            f"ensemble {ensemble}: chain shorter than {TAU_FACTOR} tau ({n} post-burn steps, "
            f"tau_max = {tau_max:.1f} steps): estimates are unreliable"
        )
    ess = min(n * walkers / tau_max, float(kept_draws)) if np.isfinite(tau_max) else 0.0
    return tau, ess, warnings


def _prepare(problem, out, *, resume, seed, start, walkers):
    """Chunk directory, density and start info (new, or loaded for ``resume``)."""
    chunks = out / CHUNK_DIR
    chunks.mkdir(parents=True, exist_ok=True)
    start_file = chunks / START_FILE
    if resume and start_file.exists():
        with open(start_file, "rb") as fh:
            info = pickle.load(fh)
        density = start.density if start is not None else log_density_setup(problem, seed=seed)
        walkers = _check_walkers(info["walkers"] if walkers is None else walkers, density.dim)
        found = {"walkers": walkers, "dim": density.dim, "seed": seed}
        for key in RESUME_KEYS:
            if info[key] != found[key]:
                raise ParameterError(
                    f"resume: {out} was run with {key}={info[key]}, found {key}={found[key]} "
                    "(use the same settings, or start again without resume)"
                )
        return chunks, density, info
    for f in list(chunks.glob("ensemble_*.pkl")) + [start_file]:
        f.unlink(missing_ok=True)
    start = prepare_start(problem, seed=seed) if start is None else start
    walkers = _check_walkers(walkers, start.density.dim)
    info = {"map_value": float(start.map_value), "map_seconds": float(start.map_seconds),
            "x_map": np.asarray(start.x_map), "covariance": np.asarray(start.covariance),
            "walkers": walkers, "dim": start.density.dim, "seed": seed}  # fmt: skip
    atomic_write_bytes(start_file, pickle.dumps(info))
    return chunks, start.density, info


def run_emcee(problem: Problem, out_dir, *, ensembles: int = 2, walkers: int | None = None,
              steps: int = 2000, burn: int | None = None, thin: int = 1, seed: int = 0,
              chunk: int = 500, resume: bool = False, progress: bool = True,
              start: Start | None = None) -> SamplerRun:  # fmt: skip
    """emcee's stretch-move ensemble sampler on the model's posterior (module docstring).

    Parameters
    ----------
    problem : Problem
    out_dir : path
        ``out_dir/chunks_emcee`` receives the chains as they are made.
    ensembles : int
        Independent ensembles, run one after another; each is one "chain" of the result.
    walkers : int, optional
        Walkers per ensemble; default ``2 * dim + 2``, at least ``2 * dim``.
    steps : int
        Steps per ensemble (each step moves every walker once).
    burn : int, optional
        Steps discarded at the start of each ensemble; default ``steps // 2``.
    thin : int
        Keep every ``thin``-th post-burn step.
    seed : int
        Seeds the MAP search, each ensemble's initial scatter and its moves.
    chunk : int
        Steps per saved chunk.
    resume : bool
        Continue from ``out_dir/chunks_emcee`` (same walkers and seed) instead of starting
        again; ensembles already at ``steps`` are only loaded.
    progress : bool
        emcee's progress bar (one per chunk).
    start : Start, optional
        MAP and Laplace covariance (:func:`heli_uq.inference.prepare_start`); computed
        if not given.  Only its density is used when resuming.

    Returns
    -------
    SamplerRun
        ``samples[site]``: (ensembles, draws, ...) constrained values with the site names
        of NUTS, ``draws = kept steps * walkers`` (step-major); ``stats["lp"]``: log
        posterior (ensembles, draws); ``info``: settings, ``wall_seconds``, per ensemble
        ``acceptance``, ``tau`` (per coordinate of ``coordinates``, in steps),
        ``ess_emcee``, and ``warnings``.

    Raises
    ------
    ParameterError
        Invalid options, a resume with different settings, or no finite start.
    """
    burn = _check_options(ensembles, walkers, steps, burn, thin, chunk)
    t_start = time.perf_counter()
    out = pathlib.Path(out_dir)
    chunks, density, start_info = _prepare(problem, out, resume=resume, seed=seed,
                                           start=start, walkers=walkers)  # fmt: skip
    walkers = start_info["walkers"]
    per_site: dict[str, list] = {}
    lps, acceptance, taus, ess, warnings = [], [], [], [], []
    for e in range(ensembles):
        chain, lp, accepted = _run_ensemble(
            density, start_info, e, walkers=walkers, steps=steps, chunk=chunk, seed=seed,
            chunks=chunks, progress=progress, n_ensembles=ensembles,
        )  # fmt: skip
        kept = chain[burn::thin]
        tau, n_eff, warn = _autocorrelation(chain[burn:], kept.shape[0] * walkers, e)
        acc = float(np.mean(accepted) / steps)
        if acc < MIN_ACCEPTANCE:
            warn.append(f"ensemble {e}: mean acceptance fraction {acc:.3f} < {MIN_ACCEPTANCE}")
        acceptance.append(acc)
        taus.append(tau.tolist())
        ess.append(n_eff)
        warnings += warn
        for k, v in constrain_draws(density, kept.reshape(-1, chain.shape[-1])).items():
            per_site.setdefault(k, []).append(v)
        lps.append(lp[burn::thin].reshape(-1))
    samples = {k: np.stack(v) for k, v in per_site.items()}
    info = {
        "sampler": "emcee", "ensembles": ensembles, "walkers": walkers, "steps": steps,
        "burn": burn, "thin": thin, "seed": seed, "chunk": chunk,
        "wall_seconds": time.perf_counter() - t_start,
        "map_value": start_info["map_value"], "map_seconds": start_info["map_seconds"],
        "x_map": start_info["x_map"], "init_scale": INIT_SCALE,
        "acceptance": acceptance, "tau": taus, "ess_emcee": ess, "warnings": warnings,
        "coordinates": coordinate_names(density),
    }  # fmt: skip
    return SamplerRun(samples=samples, stats={"lp": np.stack(lps)}, info=info)
