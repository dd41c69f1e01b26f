"""NUTS vs emcee on the same log density at the same wall time: effective samples per second.

Prints the ratio and appends one JSON line to ``--out`` (default
``studies/results/bench_samplers.jsonl``).  Usage::

    python studies/bench_samplers.py --data experimental --error iid \\
        [--chains 4 --warmup 1000 --draws 1000] [--nuts-dir DIR]

One MAP start (:func:`heli_uq.inference.prepare_start`) is shared.  NUTS runs
``chains x (warmup + draws)``; its sampling wall time (MAP excluded) is the budget.
emcee then runs ``chains`` independent ensembles whose number of steps is set so that
the same budget is spent (from a timing of the vectorised log density), and keeps the
second half.  ``--nuts-dir`` reuses a finished ``heli-uq sample`` run instead (its
``summary.json``: ``ess_bulk_min`` and wall time minus the MAP).

ESS: for NUTS the minimum rank-normalised bulk ESS (arviz) over the sampled
coordinates; for emcee emcee's own estimate ``walkers * kept steps / max tau`` summed
over ensembles (walkers are not independent chains, so arviz's ESS over walkers is not
used), with arviz's bulk ESS over ensembles-as-chains printed alongside.
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import sys
import time

import numpyro

numpyro.set_host_device_count(int(os.environ.get("HELI_UQ_CHAINS", "4")))

import arviz as az  # noqa: E402
import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from heli_uq.data import load_data, parse_window  # noqa: E402
from heli_uq.ensemble import _log_prob_fn, run_emcee  # noqa: E402
from heli_uq.inference import prepare_start, run_nuts  # noqa: E402
from heli_uq.model import make_problem  # noqa: E402

#: Sites compared (the sampled coordinates, unconstrained or positive).
SITES = ("z", "theta0", "psi0", "omega_theta0", "omega_psi0", "sigma", "tau")


def _ess_min(samples: dict) -> float:
    data = {k: v for k, v in samples.items() if k in SITES}
    ess = az.ess(az.from_dict(posterior=data), method="bulk")
    return float(min(float(ess[k].min()) for k in ess.data_vars))


def _emcee_steps(start, budget_s: float, ensembles: int, walkers: int) -> int:
    log_prob = _log_prob_fn(start.density)
    x = np.repeat(np.asarray(start.x_map)[None], walkers, axis=0)
    log_prob(x)  # compile
    t0 = time.perf_counter()
    reps = 20
    for _ in range(reps):
        log_prob(x)
    per_step = (time.perf_counter() - t0) / reps
    return max(100, int(budget_s / (per_step * ensembles)))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", default="experimental")
    p.add_argument("--window", default=None)
    p.add_argument("--error", default="iid", choices=("iid", "ar1"))
    p.add_argument("--chains", type=int, default=4)
    p.add_argument("--warmup", type=int, default=1000)
    p.add_argument("--draws", type=int, default=1000)
    p.add_argument("--walkers", type=int, default=None)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--nuts-dir", default=None, help="reuse a finished `heli-uq sample` run")
    p.add_argument("--work", default="/tmp/heli_uq_bench_samplers")
    p.add_argument("--out", default=str(pathlib.Path(__file__).parent / "results"
                                        / "bench_samplers.jsonl"))  # fmt: skip
    args = p.parse_args(argv)

    record = load_data(args.data)
    if args.window:
        record = record.window(*parse_window(args.window))
    problem = make_problem(record, error=args.error)
    start = prepare_start(problem, seed=args.seed)
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
        nuts_ess = _ess_min(run.samples)
        nuts_info = {"divergences": int(run.stats["diverging"].sum()),
                     "mean_leapfrog_steps": float(run.stats["num_steps"].mean())}
    walkers = args.walkers or 2 * start.density.dim + 2
    steps = _emcee_steps(start, nuts_s, args.chains, walkers)
    t0 = time.perf_counter()
    em = run_emcee(problem, work / "emcee", ensembles=args.chains, walkers=walkers,
                   steps=steps, seed=args.seed, start=start, progress=False)  # fmt: skip
    emcee_s = time.perf_counter() - t0
    emcee_ess = float(np.sum(em.info["ess_emcee"]))
    emcee_ess_arviz = _ess_min(em.samples)
    row = {
        "bench": "samplers", "data": args.data, "window": args.window, "error": args.error,
        "n_samples": int(problem.n_train), "dim": int(start.density.dim),
        "nuts": {"seconds": nuts_s, "ess_bulk_min": nuts_ess, "ess_per_s": nuts_ess / nuts_s,
                 "chains": args.chains, "warmup": args.warmup, "draws": args.draws, **nuts_info},
        "emcee": {"seconds": emcee_s, "ess_min": emcee_ess, "ess_per_s": emcee_ess / emcee_s,
                  "ess_bulk_min_arviz_over_ensembles": emcee_ess_arviz,
                  "ensembles": args.chains, "walkers": walkers, "steps": steps,
                  "acceptance": em.info["acceptance"], "warnings": em.info["warnings"]},
        "jax_devices": jax.local_device_count(),
    }  # fmt: skip
    row["ratio_nuts_over_emcee"] = row["nuts"]["ess_per_s"] / max(row["emcee"]["ess_per_s"], 1e-300)
    print(f"NUTS : {nuts_ess:8.1f} ESS in {nuts_s:7.1f} s = {nuts_ess / nuts_s:8.3f} ESS/s")
    print(f"emcee: {emcee_ess:8.1f} ESS in {emcee_s:7.1f} s = {emcee_ess / emcee_s:8.3f} ESS/s "
          f"({walkers} walkers x {steps} steps x {args.chains} ensembles)")
    print(f"NUTS / emcee ESS per second: {row['ratio_nuts_over_emcee']:.1f}x")
    out = pathlib.Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    with open(out, "a") as fh:
        fh.write(json.dumps(row, default=lambda o: np.asarray(o).tolist()) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
