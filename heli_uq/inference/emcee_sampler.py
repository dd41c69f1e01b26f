"""emcee (affine-invariant ensemble sampler) on the same log density as NUTS.

The target is ``-potential(x)`` of :func:`heli_uq.inference.density.log_density_setup`,
i.e. numpyro's flat *unconstrained* vector of :func:`heli_uq.probability.heli_model`, evaluated for
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
``DIR/chunks_emcee/`` (:class:`~heli_uq.inference.checkpoint.Checkpoint`); Ctrl-C or a
crash loses at most one chunk, and ``resume=True``
continues every ensemble from its last saved state (same seed, same draws, also for a
larger ``steps`` than the interrupted run).
"""

from __future__ import annotations

import functools
import pathlib
import time

import emcee
import jax
import jax.numpy as jnp
import numpy as np

from heli_uq.errors import ParameterError
from heli_uq.inference.checkpoint import Checkpoint
from heli_uq.inference.density import LogDensity, constrain_draws, coordinate_names, log_density_setup
from heli_uq.inference.interrupt import Progress
from heli_uq.inference.manifest import run_manifest
from heli_uq.inference.sampler_run import SamplerRun
from heli_uq.inference.start import Start, initial_draws, map_parameters, prepare_start, whitening
from heli_uq.probability.problem import Problem

__all__ = ["run_emcee", "INIT_SCALE", "MAX_DIM", "TAU_FACTOR"]

#: Initial walkers: MAP + INIT_SCALE * N(0, Laplace covariance).
INIT_SCALE = 0.1
#: emcee's rule: the chain must be longer than TAU_FACTOR integrated autocorrelation times.
TAU_FACTOR = 50
#: Mean acceptance fraction below which walkers are reported as (nearly) stuck.
MIN_ACCEPTANCE = 0.1
#: Largest dimension (unconstrained coordinates) at which emcee is trusted; a larger one is
#: sampled but reported in ``warnings`` (so the run's health is UNCONVERGED): use NUTS.
#: Measured by ``studies/emcee_dimension.py`` (20 s record with a hidden yaw thrust, 2 d + 2
#: walkers, 3000 steps): acceptance 0.32 at d = 17 (mechanistic), 0.18 at d = 25 (a
#: 2-unit network of u), 0.05 at d = 33 (4 units), below :data:`MIN_ACCEPTANCE`; tau_max
#: ~ 112, 163, 166 steps (likely underestimated: every chain was shorter than 50 tau).
MAX_DIM = 25
CHUNK_DIR = "chunks_emcee"
#: Compiled batched functions kept (per underlying function of a density).
JIT_CACHE_SIZE = 8


@functools.lru_cache(maxsize=JIT_CACHE_SIZE)
def _batched_log_post(potential):
    return jax.jit(jax.vmap(lambda x: -potential(x)))


def _log_prob_fn(density: LogDensity):
    """emcee's vectorised target: ``x (n, d) -> log p (n,)`` with non-finite -> ``-inf``."""
    log_post = _batched_log_post(density.potential)

    def log_prob(x):
        lp = np.asarray(log_post(jnp.asarray(x)), dtype=float)
        return np.where(np.isfinite(lp), lp, -np.inf)

    return log_prob


def _positive_int(name: str, value) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value <= 0:
        raise ParameterError(f"{name}: expected a positive integer, found {value!r}")
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
            f"burn: expected an integer in [0, steps) = [0, {steps}), found {burn!r}"
        )
    return int(burn)


def _check_walkers(walkers, dim: int) -> int:
    walkers = 2 * dim + 2 if walkers is None else int(walkers)
    if walkers < 2 * dim:
        raise ParameterError(
            f"walkers: expected at least 2 * dimension = {2 * dim} walkers for the "
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


def _initial_walkers(log_prob, start_info, walkers: int, rng):
    """Walkers around the MAP (Laplace covariance scaled by INIT_SCALE) with a finite
    ``log_prob`` (the sampler's own target)."""
    x_map, lower = whitening(start_info)
    w = initial_draws(lambda v: log_prob(x_map + v @ lower.T), walkers, x_map.size, rng,
                      scale=INIT_SCALE, on_failure="raise")  # fmt: skip
    coords = x_map + w @ lower.T
    return coords, log_prob(coords)


def _run_ensemble(density, start_info, ensemble, *, walkers, steps, chunk, seed, checkpoint,
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
    stream = f"ensemble_{ensemble:03d}"
    records = checkpoint.load(stream)
    done = sum(r["chain"].shape[0] for r in records)
    if records:
        last = records[-1]
        state = emcee.State(last["coords"], log_prob=last["log_prob_last"],
                            random_state=last["random_state"])  # fmt: skip
    else:
        rng, random_state = _ensemble_seeds(seed, ensemble)
        coords, lp = _initial_walkers(log_prob, start_info, walkers, rng)
        state = emcee.State(coords, log_prob=lp, random_state=random_state)
    sampler = emcee.EnsembleSampler(walkers, density.dim, log_prob, vectorize=True)
    desc = f"emcee ensemble {ensemble + 1}/{n_ensembles}"
    line = Progress(progress)  # emcee's tqdm bar on a terminal, plain lines otherwise
    while done < steps:
        n = min(chunk, steps - done)
        sampler.reset()
        bar = {"desc": f"{desc}, steps {done}-{done + n}"}
        state = sampler.run_mcmc(state, n, progress=progress and line.tty, progress_kwargs=bar)
        if not line.tty:
            line.update(f"{desc}: {done + n}/{steps} steps", force=True)
        record = {"chain": sampler.get_chain(), "log_prob": sampler.get_log_prob(),
                  "accepted": np.asarray(sampler.backend.accepted).copy(),
                  "coords": np.asarray(state.coords), "log_prob_last": np.asarray(state.log_prob),
                  "random_state": state.random_state}  # fmt: skip
        checkpoint.save(stream, len(records), record)
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


def _dimension_warnings(dim: int) -> list[str]:
    """The warning for a posterior of more than :data:`MAX_DIM` coordinates (or none)."""
    if dim <= MAX_DIM:
        return []
    return [f"emcee on {dim} coordinates, more than MAX_DIM = {MAX_DIM}: the stretch move's "
            "acceptance and autocorrelation time degrade with the dimension "
            "(studies/emcee_dimension.py); use NUTS"]  # fmt: skip


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


def _prepare(problem, checkpoint: Checkpoint, *, resume, seed, start, walkers):
    """Density and start info (new, or loaded for ``resume``)."""
    manifest = run_manifest(problem, {"sampler": "emcee", "seed": seed})
    info = checkpoint.resume_info(manifest) if resume else None
    if info is not None:
        density = log_density_setup(problem.with_substeps(info["substeps"]), seed=seed)
        if walkers is not None and _check_walkers(walkers, density.dim) != info["walkers"]:
            raise ParameterError(f"resume: {checkpoint.directory} was run with walkers="
                                 f"{info['walkers']}, found walkers={walkers}; use the same "
                                 "settings or start again")  # fmt: skip
        return density, info
    start = prepare_start(problem, seed=seed) if start is None else start
    info = dict(start.info(), x_map=np.asarray(start.x_map), covariance=np.asarray(start.covariance),
                walkers=_check_walkers(walkers, start.density.dim))  # fmt: skip
    checkpoint.start_new(info, manifest)
    return start.density, info


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
        if not given.  Not used when resuming.

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
    checkpoint = Checkpoint(out / CHUNK_DIR)
    density, start_info = _prepare(problem, checkpoint, resume=resume, seed=seed, start=start,
                                   walkers=walkers)  # fmt: skip
    walkers = start_info["walkers"]
    per_site: dict[str, list] = {}
    lps, acceptance, taus, ess, warnings = [], [], [], [], _dimension_warnings(density.dim)
    for e in range(ensembles):
        chain, lp, accepted = _run_ensemble(
            density, start_info, e, walkers=walkers, steps=steps, chunk=chunk, seed=seed,
            checkpoint=checkpoint, progress=progress, n_ensembles=ensembles,
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
        **{k: v for k, v in start_info.items() if k not in ("x_map", "covariance", "walkers")},
        "map_parameters": map_parameters(density, start_info["x_map"])[0],  # a resume's too
        "init_scale": INIT_SCALE,
        "acceptance": acceptance, "tau": taus, "ess_emcee": ess, "warnings": warnings,
        "coordinates": coordinate_names(density),
    }  # fmt: skip
    return SamplerRun(samples=samples, stats={"lp": np.stack(lps)}, info=info,
                      problem=density.problem)
