"""What a NUTS run costs before its first draw: tracing and compiling numpyro's kernel on
the package's log density, with the potential passed plain or as a jitted function, and
with the prior's log-Jacobian dense instead of in closed form.

numpyro's NUTS calls the potential and its gradient at several sites of its tree
building.  A plain Python potential is traced (and differentiated, and batched over the
chains) at each of them; a jitted one is traced once per input shape and reused.
:func:`heli_uq.inference.run_nuts` passes it jitted.  For each way this script builds the
kernel's two programs with the sampler's own function (``init`` and a block of
iterations, vmapped over the chains; on the plain potential, without the sampler's
whitening map), times tracing (``lower``) and XLA compilation (``compile``) with the
persistent compilation cache off, checks that the ways give the same draws, and appends
one JSON line to ``results/bench_nuts_trace.jsonl`` with the times [s] and the ratios to
the package's way (``jit``).  Each way runs in a fresh process, the order alternating
over ``--repeats``.

The third way, ``dense_jacobian``, is the jitted potential with the log-Jacobian of the
sampling coordinates computed as the package did before the closed form
(:meth:`heli_uq.probability.Coordinates._log_jacobian`): ``slogdet`` of the forward-mode
Jacobian of the whole map.  Its draws agree with the closed form's to rounding (the
largest difference is reported), not bit for bit.

Usage: ``python studies/bench_nuts_trace.py [--seconds 1.5] [--repeats 2]``.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import subprocess
import sys
import time

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from _study import RESULTS, append_jsonl, provenance  # noqa: E402

WAYS = ("plain", "jit", "dense_jacobian")
#: NUTS iterations of the timed block (its length is a traced argument, as in the sampler).
BLOCK = 3


def measure(way: str, seconds: float) -> dict:
    """Trace and compile times [s] of the kernel's programs for one way, in this process."""
    # isort: off
    import heli_uq  # noqa: F401  (first: its JAX settings act only if JAX is not imported yet)
    import jax
    import jax.numpy as jnp
    # isort: on
    from numpyro.infer import NUTS

    from heli_uq.inference.density import log_density_setup
    from heli_uq.inference.nuts_blocks import chain_functions
    from heli_uq.probability import make_problem
    from heli_uq.simulation import synthetic_experiment

    jax.config.update("jax_enable_x64", True)
    jax.config.update("jax_compilation_cache_dir", None)
    if way == "dense_jacobian":
        from heli_uq.probability.coordinates import Coordinates

        def dense(self, z, mapped=None):
            if self.resolved == "log":
                return jnp.zeros(())
            return jnp.linalg.slogdet(jax.jacfwd(self.prior_coordinates)(z))[1]

        Coordinates._log_jacobian = dense
    record = synthetic_experiment(duration=seconds, seed=1, noise_std=(0.003, 0.003))
    density = log_density_setup(make_problem(record, error="iid"))
    potential = density.potential if way == "plain" else density.potential_jit
    kernel = NUTS(potential_fn=potential, dense_mass=True, max_tree_depth=6)
    init, block = chain_functions(kernel, 10, parallel=False)  # the sampler's own programs
    keys = jax.random.split(jax.random.PRNGKey(0), 2)
    xs = jnp.stack([jnp.asarray(density.x_init)] * 2)
    out = {}
    t = time.perf_counter()
    lowered = init.lower(keys, xs)
    out["init_trace_s"] = time.perf_counter() - t
    t = time.perf_counter()
    state = lowered.compile()(keys, xs)
    out["init_compile_s"] = time.perf_counter() - t
    t = time.perf_counter()
    lowered = block.lower(state, BLOCK)
    out["block_trace_s"] = time.perf_counter() - t
    t = time.perf_counter()
    compiled = lowered.compile()
    out["block_compile_s"] = time.perf_counter() - t
    state, _ = compiled(state, BLOCK)
    out["draws"] = np.asarray(state.z).tolist()
    out["dim"] = int(density.dim)
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=1.5, help="synthetic record length [s]")
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--out", default=str(RESULTS / "bench_nuts_trace.jsonl"))
    ap.add_argument("--one", choices=WAYS, help=argparse.SUPPRESS)  # a child process
    args = ap.parse_args(argv)
    if args.one:
        print(json.dumps(measure(args.one, args.seconds)))
        return 0
    t0 = time.perf_counter()
    runs = {w: [] for w in WAYS}
    for r in range(args.repeats):
        for way in WAYS if r % 2 == 0 else WAYS[::-1]:
            cmd = [sys.executable, __file__, "--one", way, "--seconds", str(args.seconds)]
            done = subprocess.run(cmd, capture_output=True, text=True, check=True)
            runs[way].append(json.loads(done.stdout.strip().splitlines()[-1]))
    same = all(np.array_equal(a["draws"], runs["plain"][0]["draws"]) for w in WAYS[:2] for a in runs[w])
    dense_diff = max(float(np.max(np.abs(np.subtract(a["draws"], runs["jit"][0]["draws"]))))
                     for a in runs["dense_jacobian"])  # fmt: skip
    keys = ("init_trace_s", "init_compile_s", "block_trace_s", "block_compile_s")
    med = {w: {k: float(np.median([m[k] for m in runs[w]])) for k in keys} for w in WAYS}
    total = {w: sum(med[w].values()) for w in WAYS}
    ratios = {w: {k: med[w][k] / med["jit"][k] for k in keys} for w in ("plain", "dense_jacobian")}
    row = {"seconds": args.seconds, "dim": runs["jit"][0]["dim"], "repeats": args.repeats,
           "median_s": med, "plain_over_jit": ratios["plain"], "total_s": total,
           "total_plain_over_jit": total["plain"] / total["jit"], "same_draws": bool(same),
           "dense_jacobian_over_jit": ratios["dense_jacobian"],
           "total_dense_jacobian_over_jit": total["dense_jacobian"] / total["jit"],
           "dense_jacobian_max_draw_difference": dense_diff,
           **provenance(__file__, argv, time.perf_counter() - t0)}  # fmt: skip
    for w in WAYS:
        print(f"{w:14s}: " + ", ".join(f"{k} {med[w][k]:.1f}" for k in keys) + f"; total {total[w]:.1f} s")
    for w, ratio in ratios.items():
        print(f"{w} / jit: " + ", ".join(f"{k} {v:.2f}x" for k, v in ratio.items())
              + f"; total {total[w] / total['jit']:.2f}x")
    print(f"plain and jit same draws: {same}; dense_jacobian's largest difference: {dense_diff:.1e}")
    append_jsonl(args.out, row)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
