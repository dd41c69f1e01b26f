"""NUTS (numpyro) in coordinates whitened by the Laplace approximation, saved in chunks.

The metric is the Laplace covariance with each eigen-axis rescaled to the posterior's
width (:mod:`heli_uq.inference.level_scale`).

The sampler starts from the multi-start MAP (:func:`heli_uq.inference.prepare_start`),
so chains do not start in the regime where the model flies off.  Draws are produced
``chunk`` at a time after warm-up and written with the sampler state
(:class:`~heli_uq.inference.checkpoint.Checkpoint`), so ``resume=True`` continues an
interrupted run with the same seed stream (same seed, same draws).

The chains advance in short compiled *blocks* of NUTS iterations (numpyro's kernel, all
chains at once: one device per chain when there are enough, else vectorised;
:mod:`heli_uq.inference.nuts_blocks`), each cut to about :data:`BLOCK_SECONDS` of work.
Between blocks the sampler reports progress (warm-up or sampling, iterations, divergences
per chain) and honours an interrupt: the first SIGINT saves the draws finished so far (or
the warm-up state) and raises :class:`~heli_uq.inference.interrupt.Interrupted`;
``resume=True`` then continues to the same draws, bit for bit, as an uninterrupted run
(every iteration runs the same compiled step, whatever the block lengths).
"""

from __future__ import annotations

import logging
import pathlib
import time

import jax
import jax.numpy as jnp
import numpy as np
from numpyro.infer import NUTS

from heli_uq.errors import ParameterError
from heli_uq.inference import warmup_limit
from heli_uq.inference.checkpoint import Checkpoint
from heli_uq.inference.density import coordinate_names, log_density_setup
from heli_uq.inference.draw_memory import check_draws_memory
from heli_uq.inference.interrupt import Interrupted, Progress, deferred_interrupt
from heli_uq.inference.level_scale import level_scaled_covariance
from heli_uq.inference.manifest import run_manifest
from heli_uq.inference.nuts_blocks import (
    BLOCK_MAX,
    chain_functions,
    constrained_draws,
    progress_text,
    save_chunk,
)
from heli_uq.inference.sampler_run import SamplerRun
from heli_uq.inference.start import Start, initial_draws, map_parameters, prepare_start
from heli_uq.inference.whiten import SamplerMap, choose_walls
from heli_uq.probability.problem import Problem

__all__ = ["run_nuts", "resume_obstacle", "TARGET_ACCEPT", "MIN_DRAWS_AT_LIMIT"]

#: Default target acceptance of the step-size adaptation.  On the full rig record
#: (4 x (1000 + 1000), iid errors), with one-sided walls mapped (:mod:`whiten`): 0.9 gave
#: no divergence, 9.5 leapfrog steps per draw and 9.7 min; 0.95 none, 13.7 steps and
#: 10.9 min.  (Before the wall map 0.9 gave 1 divergence in 4000 draws.)
TARGET_ACCEPT = 0.9
CHUNK_DIR = "chunks"
#: Default draws per saved chunk.
CHUNK = 250
#: Target wall time of one block [s]: the latency of an interrupt and of progress lines.
BLOCK_SECONDS = 2.0
#: Iterations of the first block (it includes compiling, so it sets no pace).
FIRST_BLOCK = 2
#: Fewest draws per chain a run stopped by its ``time_limit`` keeps (all of them if fewer
#: are asked for): below that its ESS and R-hat say little.
MIN_DRAWS_AT_LIMIT = 100


def _fresh_start(problem: Problem, start: Start | None, seed: int):
    """``(info, density)`` of a new run: the MAP start (computed if ``start`` is None), its
    level-scaled Laplace covariance as the metric and the coordinates mapped for a
    one-sided wall (module :mod:`heli_uq.inference.whiten`)."""
    start = prepare_start(problem, seed=seed) if start is None else start
    info = dict(start.info(), x_map=np.asarray(start.x_map), covariance=np.asarray(start.covariance))
    potential = start.density.potential_jit
    info["covariance"], factors = level_scaled_covariance(potential, info["x_map"], start.map_value,
                                                          info["covariance"])  # fmt: skip
    info["metric_factors"] = [float(f) for f in factors]
    logs = [i for i, name in enumerate(coordinate_names(start.density)) if name.startswith("z[log_")]
    info["walls"] = [list(w) for w in choose_walls(potential, info["x_map"], info["covariance"], logs)]
    return info, start.density


def _manifest(problem: Problem, **settings) -> dict:
    """The manifest of a NUTS run; ``settings``: the arguments of :func:`run_nuts` that make its draws."""
    return run_manifest(problem, {"sampler": "nuts", **settings})


def resume_obstacle(problem: Problem, out_dir, *, chains: int, warmup: int, draws: int, seed: int,
                    max_tree_depth: int, target_accept: float, adapt_mass_matrix: bool,
                    chunk: int = CHUNK, refuse: bool = False) -> str | None:
    """Why :func:`run_nuts` with these arguments cannot continue the run in ``out_dir/chunks``
    (:meth:`~heli_uq.inference.checkpoint.Checkpoint.obstacle`); None if ``resume=True`` would.
    ``refuse``: raise the :class:`ParameterError` that ``run_nuts(resume=True)`` would
    instead (a caller that announces the resume checks it first)."""
    checkpoint = Checkpoint(pathlib.Path(out_dir) / CHUNK_DIR)
    manifest = _manifest(problem, chains=chains, warmup=warmup, draws=draws, chunk=chunk, seed=seed,
                         max_tree_depth=max_tree_depth, target_accept=target_accept,
                         adapt_mass_matrix=adapt_mass_matrix)  # fmt: skip
    if refuse:
        checkpoint.resume_info(manifest)
    return checkpoint.obstacle(manifest)


def run_nuts(problem: Problem, out_dir, *, chains: int = 4, warmup: int = 1000,
             draws: int = 1000, seed: int = 0, chunk: int = CHUNK, resume: bool = False,
             progress: bool = True, max_tree_depth: int = 8,
             target_accept: float = TARGET_ACCEPT, adapt_mass_matrix: bool = True,
             start: Start | None = None, time_limit: float | None = None,
             max_draws: int | None = None, converged=None) -> SamplerRun:  # fmt: skip
    """NUTS in coordinates whitened by the Laplace approximation at the MAP.

    NUTS moves in ``w`` with ``x = x_map + L w`` (``x``: numpyro's unconstrained vector,
    ``L L^T``: the Laplace covariance), where the posterior is close to ``N(0, I)``; the
    Jacobian of this map is constant, so the target is unchanged.  Coordinates whose
    posterior has a one-sided exponential wall (a weakly identified positive parameter,
    e.g. ``J_s``), at the MAP or along the ridge the Laplace approximation follows, get a
    ``log softplus`` map in addition, with its Jacobian
    (:class:`~heli_uq.inference.whiten.SamplerMap`, chosen by
    :func:`~heli_uq.inference.whiten.choose_walls`; ``wall_coordinates`` and
    ``wall_sides`` in the run's info name them): on the rig record this lets the step
    size double.  Warm-up adapts the step
    size and a dense mass matrix *in w*, starting from the identity.

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
        Draws per saved chunk (an interrupt also saves the draws finished so far).
    resume : bool
        Continue from ``out_dir/chunks`` (same manifest, else an error; nothing saved
        there is an error too) instead of starting again.
    progress : bool
        Status lines on stderr (module :mod:`heli_uq.inference.interrupt`).
    target_accept : float
        Target mean acceptance probability of step-size adaptation.
    adapt_mass_matrix : bool
        Adapt the dense mass matrix in whitened coordinates during warm-up (``False``:
        keep the identity, i.e. the level-scaled Laplace covariance).
    start : Start, optional
        The MAP start; computed if not given.
    time_limit : float, optional
        Wall seconds from the call after which sampling stops at the end of the current
        block, once every chain has :data:`MIN_DRAWS_AT_LIMIT` draws.  The draws made are
        kept and saved; ``info["draws_requested"]`` records the number asked for, and a
        ``resume`` with the same settings continues to it.  A warm-up that would not leave
        time for those draws (timed over its first iterations) starts again, from the
        chains' current positions, with the iterations that fit and the step size alone
        adapted (:mod:`heli_uq.inference.warmup_limit`; ``info["warmup_requested"]``).
        Not part of the run's settings: it changes how many draws there are and how
        long the warm-up is, not the target.
    max_draws : int, optional
        With ``converged``: once the requested ``draws`` are made, sampling continues a
        ``chunk`` at a time while ``converged`` says the draws so far have not, up to
        ``max_draws`` per chain (and the time limit).  ``info["draws_extended_from"]``
        then records the request.  Not part of the run's settings either.
    converged : callable, optional
        ``converged(samples) -> bool`` on the named constrained draws so far (arrays of
        shape (chains, draws, ...)): the caller's convergence checks
        (:func:`heli_uq.output.diagnostics.draws_converged`).

    Raises
    ------
    ParameterError
        Invalid options, or a resume under different settings or with nothing to resume.
    Interrupted
        After a SIGINT, at the end of the current block, once the finished draws (or the
        warm-up state) are saved.
    """
    for name, value in (("chains", chains), ("warmup", warmup), ("draws", draws),
                        ("chunk", chunk)):  # fmt: skip
        if isinstance(value, bool) or int(value) != value or int(value) <= 0:
            raise ParameterError(f"{name}: expected a positive integer, found {value!r}")
    if not 0.0 < target_accept < 1.0:
        raise ParameterError(f"target_accept: expected a number in (0, 1), found {target_accept!r}")
    if time_limit is not None and not time_limit >= 0:
        raise ParameterError(f"time_limit: expected seconds >= 0, found {time_limit!r}")
    if max_draws is not None and (isinstance(max_draws, bool) or int(max_draws) != max_draws
                                  or converged is None):  # fmt: skip
        raise ParameterError(f"max_draws: expected an integer with a convergence check, found {max_draws!r}")
    most = max(draws, max_draws or 0)
    check_draws_memory(problem, chains * most, f"draws: {chains} chains x {most} draws")
    t_start = time.perf_counter()
    checkpoint = Checkpoint(pathlib.Path(out_dir) / CHUNK_DIR)
    manifest = _manifest(problem, chains=chains, warmup=warmup, draws=draws, chunk=chunk, seed=seed,
                         max_tree_depth=max_tree_depth, target_accept=target_accept,
                         adapt_mass_matrix=adapt_mass_matrix)  # fmt: skip
    info = checkpoint.resume_info(manifest) if resume else None
    records = checkpoint.load("nuts") if info is not None else []
    warm_record = checkpoint.load("nuts_warmup") if info is not None else []
    if info is None:
        info, density = _fresh_start(problem, start, seed)
        checkpoint.start_new(info, manifest)
    else:
        density = log_density_setup(problem.with_substeps(info["substeps"]), seed=seed)
    problem = density.problem
    smap = SamplerMap.from_info(info)
    requested_warmup = warmup
    if "warmup_cut" in info:  # a resumed run whose warm-up its time limit cut
        warmup, adapt_mass_matrix = info["warmup_cut"]["used"], False

    def potential(w):
        x, log_det = smap.x_and_log_det(w)
        return density.potential(x) - log_det

    # jit: the kernel calls the potential (and its gradient) at several sites of its tree
    # building; as a jitted function it is traced and differentiated once and reused there
    # (tracing a block of the base model on a 0.5 s record 3.7-5.3x faster:
    # studies/bench_nuts_trace.py).
    potential_jit = jax.jit(potential)

    def kernel_blocks(warmup, adapt_mass_matrix):
        kernel = NUTS(potential_fn=potential_jit, dense_mass=True, max_tree_depth=max_tree_depth,
                      target_accept_prob=target_accept, adapt_mass_matrix=adapt_mass_matrix)
        return chain_functions(kernel, warmup, parallel)

    parallel = jax.local_device_count() >= chains and chains > 1
    init, block = kernel_blocks(warmup, adapt_mass_matrix)
    done = sum(r["x"].shape[1] for r in records)
    requested_draws = draws
    if max_draws is not None and done > draws:  # resumed after continuing past the request
        draws = min(done, max_draws)
    warm_seconds = 0.0
    if records or warm_record:
        saved = records[-1] if records else warm_record[-1]
        state, it = saved["state"], (warmup + done if records else int(saved["iteration"]))
        # numpyro builds the kernel's step function in ``init``: trace it (no computation)
        # so that the loaded state can be continued.
        jax.eval_shape(init, jax.random.split(jax.random.PRNGKey(seed), chains), state.z)
    else:
        rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(1,)))
        # The finiteness check runs the density's own compiled potential draw by draw (the
        # MAP compiled it) instead of compiling a batched one for a few evaluations.  It
        # leaves out the map's log-determinant, which is finite: only finiteness decides.
        def log_density(w):
            return np.array([-float(density.potential_jit(x)) for x in smap.x(w)])

        w0 = initial_draws(log_density, chains, smap.x_map.size, rng, on_failure="map")
        keys = jax.random.split(jax.random.PRNGKey(seed), chains)
        state, it = init(keys, jnp.asarray(w0)), 0
    # Size the warm-up to the time limit in a fresh run, at the pace measured after the
    # first block (compiling) and the first iterations (warmup_limit.PaceMeter), and again
    # if a kept warm-up falls behind; at most one cut.
    sizing = time_limit is not None and it == 0 and not records and not warm_record
    meter, decided = warmup_limit.PaceMeter(FIRST_BLOCK), False
    first_block_seconds = 0.0
    total = warmup + draws
    if (records and it == total and max_draws is not None and draws < max_draws
            and not converged(constrained_draws(density, records, chains))):  # fmt: skip
        draws = min(draws + chunk, max_draws)  # a finished run resumed to go on while unconverged
        total = warmup + draws
    bar = Progress(progress)
    pending: list[tuple] = []
    n_block, t_loop, paced = FIRST_BLOCK, time.perf_counter(), False
    with deferred_interrupt() as flag:
        while it < total:
            limit = warmup if it < warmup else warmup + min(draws, (done // chunk + 1) * chunk)
            n = min(n_block, limit - it)
            t0 = time.perf_counter()
            state, out = block(state, n)
            out = jax.device_get(out)
            seconds = time.perf_counter() - t0
            if it < warmup:
                warm_seconds += seconds
                first_block_seconds = first_block_seconds or seconds
            else:
                pending.append(tuple(np.asarray(o)[:, :n] for o in out))
            it += n
            pace = meter.update(it, warm_seconds) if sizing and it < warmup else None
            n_min = min(draws, MIN_DRAWS_AT_LIMIT)
            left = None if pace is None else time_limit - (time.perf_counter() - t_start)
            if pace is not None and not (decided and pace * (warmup - it + n_min) <= left):
                decided = True
                cut = warmup_limit.sized_warmup(warmup, draws, it, pace, left, first_block_seconds, n_min)
                if cut is not None:
                    sizing = False
                    # what a resume needs (the requested length is in the manifest)
                    info["warmup_cut"] = {"used": cut, "pace_s": pace, "discarded_iterations": it}
                    checkpoint.update_start(info)
                    warmup, adapt_mass_matrix, total = cut, False, cut + draws
                    init, block = kernel_blocks(warmup, adapt_mass_matrix)
                    keys = jax.random.split(jax.random.fold_in(jax.random.PRNGKey(seed), 1), chains)
                    state, it, warm_seconds, n_block, paced = init(keys, state.z), 0, 0.0, FIRST_BLOCK, False
                    bar.close()  # ends a status line before the message
                    logging.getLogger(__name__).info(
                        f"NUTS warm-up cut from {requested_warmup} to {cut} iterations (step size only) "
                        f"to leave time for {n_min} draws per chain before the time limit, at "
                        f"{pace:.2g} s per iteration")
                    continue
            if paced:  # the first block compiles: the pace is taken from the later ones
                n_block = int(np.clip(round(BLOCK_SECONDS * n / max(seconds, 1e-9)), 1, BLOCK_MAX))
            paced = True
            bar.update(progress_text(it, warmup, draws, chains, pending, records,
                                      time.perf_counter() - t_loop))  # fmt: skip
            if it == limit and pending:
                records.append(save_chunk(checkpoint, len(records), pending, state, smap))
                done, pending = done + records[-1]["x"].shape[1], []
            if flag.requested and it < total:
                if pending:
                    records.append(save_chunk(checkpoint, len(records), pending, state, smap))
                    done = done + records[-1]["x"].shape[1]
                if it <= warmup:
                    checkpoint.save("nuts_warmup", 0, {"state": state, "iteration": it})
                    saved = f"warm-up state after {it} of {warmup} iterations"
                else:
                    saved = f"{done} of {draws} draws per chain"
                bar.close()
                raise Interrupted(f"{saved} saved in {checkpoint.directory}")
            kept = done + sum(part[0].shape[1] for part in pending)
            if (time_limit is not None and it < total and it > warmup
                    and kept >= min(draws, MIN_DRAWS_AT_LIMIT)
                    and time.perf_counter() - t_start > time_limit):  # fmt: skip
                if pending:
                    records.append(save_chunk(checkpoint, len(records), pending, state, smap))
                    done, pending = done + records[-1]["x"].shape[1], []
                if done < requested_draws:
                    info["draws_requested"] = requested_draws
                draws = done
                break
            if (it == total and max_draws is not None and draws < max_draws and not flag.requested
                    and (time_limit is None or time.perf_counter() - t_start < time_limit)
                    and not converged(constrained_draws(density, records, chains))):  # fmt: skip
                draws = min(draws + chunk, max_draws)
                total = warmup + draws
    bar.close(progress_text(it, warmup, draws, chains, [], records, time.perf_counter() - t_loop))
    if flag.requested:  # in the last block: every draw is saved, stop before post-processing
        raise Interrupted(f"all {draws} draws per chain saved in {checkpoint.directory}")
    method = "parallel" if parallel else "vectorized"
    samples = constrained_draws(density, records, chains, draws)
    stats = {k: np.concatenate([r["stats"][k] for r in records], axis=1)[:, :draws]
             for k in records[0]["stats"]}  # fmt: skip
    out_info = {k: v for k, v in info.items() if k not in ("x_map", "covariance")}
    out_info["map_parameters"] = map_parameters(density, info["x_map"])[0]  # a resume's too
    if warmup != requested_warmup:
        out_info["warmup_requested"] = requested_warmup
    if draws > requested_draws:
        out_info["draws_extended_from"] = requested_draws
    out_info.update(sampler="nuts", chains=chains, warmup=warmup, draws=draws, seed=seed,
                    adapt_mass_matrix=adapt_mass_matrix,
                    chain_method=method, warmup_seconds=warm_seconds,
                    coordinates="laplace_whitened",
                    wall_coordinates=[coordinate_names(density)[i] for i in smap.indices],
                    wall_sides=["above" if w.side > 0 else "below" for w in smap.walls],
                    step_size=np.asarray(state.adapt_state.step_size).tolist(),
                    target_accept=target_accept, max_tree_depth=max_tree_depth,
                    wall_seconds=time.perf_counter() - t_start)  # fmt: skip
    return SamplerRun(samples=samples, stats=stats, info=out_info, problem=problem)
