"""NUTS vs emcee on the same log density at the same wall time: effective samples per second.

Prints the ratio and appends one JSON line to ``--out`` (default
``studies/results/bench_samplers.jsonl``).  Usage::

    python studies/bench_samplers.py --data experimental --error iid \\
        [--chains 4 --warmup 1000 --draws 1000] [--nuts-dir DIR]
    python studies/bench_samplers.py --window 0:3 --chains 2 --warmup 20 --draws 20  # smoke

One MAP start (:func:`heli_uq.inference.prepare_start`) is shared.  NUTS runs
``chains x (warmup + draws)``; its sampling wall time (MAP excluded) is the budget.
emcee then runs ``chains`` independent ensembles whose number of steps is set so that
the same budget is spent (from a timing of the vectorised log density), and keeps the
second half.  ``--nuts-dir`` reuses a finished ``heli-uq sample`` run instead (its
``summary.json``: ``ess_bulk_min`` and wall time minus the MAP).

ESS: for NUTS the minimum rank-normalised bulk ESS (arviz) over the sampled sites
(coordinates ``z``, free initial-state entries, residual scales and correlation times;
not ``scale_noise``, the common inertia scale, whose posterior is its prior); for emcee
emcee's own estimate ``walkers * kept steps / max tau`` summed over ensembles (walkers
are not independent chains, so arviz's ESS over walkers is not used), with arviz's bulk
ESS over ensembles-as-chains recorded alongside.  Times in seconds.  NUTS runs its
chains in parallel on ``--chains`` XLA host devices (set before JAX starts), as
``heli-uq sample`` does.  The JSON line also records the package and JAX versions, the
command line and the wall time of the whole run.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys
import time

import arviz as az
import jax
import numpy as np
import numpyro

from heli_uq.data import load_data, parse_window
from heli_uq.inference import prepare_start, run_emcee, run_nuts
from heli_uq.inference.emcee_sampler import _log_prob_fn
from heli_uq.probability import make_problem

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from _study import RESULTS, append_jsonl, provenance  # noqa: E402

#: Sampled site left out of the ESS comparison (the common inertia scale: exactly its
#: prior, independent of the data, when every inertia-scaled prior is log-normal).
NOT_COMPARED = ("scale_noise",)
#: Log-density evaluations timed to turn the NUTS budget into emcee steps.
TIMING_CALLS = 20
#: Fewest emcee steps per ensemble.
MIN_EMCEE_STEPS = 100


def compared_sites(density) -> tuple[str, ...]:
    """The sampled sites of the density (its unconstrained vector), minus NOT_COMPARED."""
    return tuple(k for k in density.unravel(density.x_init) if k not in NOT_COMPARED)


def _ess_min(samples: dict, sites) -> float:
    data = {k: v for k, v in samples.items() if k in sites}
    ess = az.ess(az.from_dict(posterior=data), method="bulk")
    return float(min(float(ess[k].min()) for k in ess.data_vars))


def _emcee_steps(start, budget_s: float, ensembles: int, walkers: int) -> int:
    log_prob = _log_prob_fn(start.density)
    x = np.repeat(np.asarray(start.x_map)[None], walkers, axis=0)
    log_prob(x)  # compile
    t0 = time.perf_counter()
    for _ in range(TIMING_CALLS):
        log_prob(x)
    per_step = (time.perf_counter() - t0) / TIMING_CALLS
    return max(MIN_EMCEE_STEPS, int(budget_s / (per_step * ensembles)))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", default="experimental", help="record: 'experimental' or CSV path")
    p.add_argument("--window", default=None, metavar="A:B", help="use only A <= t < B [s]")
    p.add_argument("--error", default="iid", choices=("iid", "ar1"))
    p.add_argument("--chains", type=int, default=4, help="NUTS chains = emcee ensembles")
    p.add_argument("--warmup", type=int, default=1000, help="NUTS warm-up per chain")
    p.add_argument("--draws", type=int, default=1000, help="NUTS draws per chain")
    p.add_argument("--walkers", type=int, default=None, help="emcee walkers (default 2 dim + 2)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--nuts-dir", default=None, help="reuse a finished `heli-uq sample` run")
    p.add_argument("--work", default="/tmp/heli_uq_bench_samplers",
                   help="directory of the samplers' chunks")
    p.add_argument("--out", default=str(RESULTS / "bench_samplers.jsonl"))
    args = p.parse_args(argv)
    t_run = time.perf_counter()
    # One XLA host device per NUTS chain (parallel chains, as ``heli-uq sample``); only
    # effective before JAX's backend starts, i.e. before the first computation.
    numpyro.set_host_device_count(args.chains)

    record = load_data(args.data)
    if args.window:
        record = record.window(*parse_window(args.window))
    problem = make_problem(record, error=args.error)
    start = prepare_start(problem, seed=args.seed)
    sites = compared_sites(start.density)
    work = pathlib.Path(args.work)
    if args.nuts_dir:
        summary = json.loads((pathlib.Path(args.nuts_dir) / "summary.json").read_text())
        nuts_s = float(summary["wall_s"]) - float(summary.get("map_seconds", 0.0))
        nuts_ess = float(summary["ess_bulk_min"])
        nuts_info = {k: summary.get(k) for k in ("divergences", "mean_leapfrog_steps",
                                                  "rhat_max")}  # fmt: skip
    else:
        t0 = time.perf_counter()
        run = run_nuts(problem, work / "nuts", chains=args.chains, warmup=args.warmup,
                       draws=args.draws, seed=args.seed, start=start, progress=False)
        nuts_s = time.perf_counter() - t0
        nuts_ess = _ess_min(run.samples, sites)
        nuts_info = {"divergences": int(run.stats["diverging"].sum()),
                     "mean_leapfrog_steps": float(run.stats["num_steps"].mean())}
    walkers = args.walkers or 2 * start.density.dim + 2
    steps = _emcee_steps(start, nuts_s, args.chains, walkers)
    t0 = time.perf_counter()
    em = run_emcee(problem, work / "emcee", ensembles=args.chains, walkers=walkers,
                   steps=steps, seed=args.seed, start=start, progress=False)  # fmt: skip
    emcee_s = time.perf_counter() - t0
    emcee_ess = float(np.sum(em.info["ess_emcee"]))
    emcee_ess_arviz = _ess_min(em.samples, sites)
    row = {
        "bench": "samplers", "data": args.data, "window": args.window, "error": args.error,
        "n_samples": int(problem.n_train), "dim": int(start.density.dim),
        "nuts": {"seconds": nuts_s, "ess_bulk_min": nuts_ess, "ess_per_s": nuts_ess / nuts_s,
                 "chains": args.chains, "warmup": args.warmup, "draws": args.draws, **nuts_info},
        "emcee": {"seconds": emcee_s, "ess_min": emcee_ess, "ess_per_s": emcee_ess / emcee_s,
                  "ess_bulk_min_arviz_over_ensembles": emcee_ess_arviz,
                  "ensembles": args.chains, "walkers": walkers, "steps": steps,
                  "acceptance": em.info["acceptance"], "warnings": em.info["warnings"]},
        "jax_devices": jax.local_device_count(), "ess_sites": list(sites),
    }  # fmt: skip
    row["ratio_nuts_over_emcee"] = row["nuts"]["ess_per_s"] / max(row["emcee"]["ess_per_s"], 1e-300)
    print(f"NUTS : {nuts_ess:8.1f} ESS in {nuts_s:7.1f} s = {nuts_ess / nuts_s:8.3f} ESS/s")
    print(f"emcee: {emcee_ess:8.1f} ESS in {emcee_s:7.1f} s = {emcee_ess / emcee_s:8.3f} ESS/s "
          f"({walkers} walkers x {steps} steps x {args.chains} ensembles)")
    print(f"NUTS / emcee ESS per second: {row['ratio_nuts_over_emcee']:.3g}x")
    row.update(provenance(__file__, argv, time.perf_counter() - t_run))
    print(f"appended to {append_jsonl(args.out, row)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
