"""The compiled blocks of NUTS iterations that :func:`heli_uq.inference.nuts.run_nuts`
advances its chains by, the chunks it saves their draws in, and its progress line.

A block is ``n`` iterations of numpyro's NUTS kernel for every chain at once (one device
per chain when there are enough, else vectorised), ``n`` traced so that one compilation
serves every block length; its output buffers hold :data:`BLOCK_MAX` iterations.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from heli_uq.inference.checkpoint import Checkpoint
from heli_uq.inference.density import constrain_draws
from heli_uq.inference.whiten import SamplerMap

__all__ = ["chain_functions", "save_chunk", "progress_text", "constrained_draws", "BLOCK_MAX",
           "NUTS_EXTRA_FIELDS"]  # fmt: skip

#: Per-iteration sampler statistics kept with each draw (numpyro's ``HMCState`` fields).
NUTS_EXTRA_FIELDS = ("diverging", "num_steps", "energy", "accept_prob", "potential_energy")
#: Most NUTS iterations per compiled block (the size of its output buffers).
BLOCK_MAX = 50


def chain_functions(kernel, warmup: int, parallel: bool):
    """``init(keys, w0) -> state`` and ``block(state, n) -> (state, out)`` for all chains:
    ``n`` (<= :data:`BLOCK_MAX`, traced: one compilation) NUTS iterations of every chain,
    ``out`` = per-iteration ``(w, diverging, num_steps, energy, accept_prob,
    potential_energy)`` in buffers of :data:`BLOCK_MAX` rows (the first ``n`` are set)."""

    def init_one(key, w0):
        return kernel.init(key, warmup, w0, (), {})

    def fields(s):
        return (s.z, s.diverging, s.num_steps, s.energy, s.accept_prob, s.potential_energy)

    def block_one(state, n):
        def body(i, carry):
            s, out = carry
            s = kernel.sample(s, (), {})
            return s, tuple(o.at[i].set(v) for o, v in zip(out, fields(s), strict=True))

        out = tuple(jnp.zeros((BLOCK_MAX,) + jnp.shape(v), jnp.result_type(v)) for v in fields(state))
        return lax.fori_loop(0, n, body, (state, out))

    if parallel:
        return jax.pmap(init_one), jax.pmap(block_one, in_axes=(0, None))
    return jax.jit(jax.vmap(init_one)), jax.jit(jax.vmap(block_one, in_axes=(0, None)))


def save_chunk(checkpoint: Checkpoint, index: int, pending: list, state, smap: SamplerMap) -> dict:
    """Write the draws of ``pending`` blocks (``w`` -> sampler coordinates ``x``) with the
    state to continue from, as chunk ``index``; returns the record."""
    w, *stats = (np.concatenate(parts, axis=1) for parts in zip(*pending, strict=True))
    record = {"x": smap.x(w), "stats": dict(zip(NUTS_EXTRA_FIELDS, stats, strict=True)),
              "state": jax.device_get(state)}  # fmt: skip
    checkpoint.save("nuts", index, record)
    return record


def progress_text(it: int, warmup: int, draws: int, chains: int, pending: list, records: list,
                  seconds: float) -> str:  # fmt: skip
    """``"NUTS sampling (4 chains): 120/500 draws, 35 s; divergences per chain 0 0 1 0"``."""
    if it <= warmup and not records and not pending:
        return f"NUTS warm-up ({chains} chains): {it}/{warmup} iterations, {seconds:.0f} s"
    div = [r["stats"]["diverging"] for r in records] + [p[1] for p in pending]
    per_chain = np.concatenate(div, axis=1).sum(axis=1) if div else np.zeros(chains, int)
    return (f"NUTS sampling ({chains} chains): {it - warmup}/{draws} draws, {seconds:.0f} s; "
            "divergences per chain " + " ".join(str(int(d)) for d in per_chain))


def constrained_draws(density, records: list[dict], chains: int, draws: int | None = None) -> dict:
    """The saved chunks' first ``draws`` per chain, named and constrained: (chains, draws, ...)."""
    x = np.concatenate([r["x"] for r in records], axis=1)[:, :draws]
    flat = constrain_draws(density, x.reshape(-1, x.shape[-1]))
    return {k: v.reshape((chains, x.shape[1]) + v.shape[1:]) for k, v in flat.items()}
