"""Simulation-based calibration (SBC) of the NUTS posterior on short synthetic records.

For each replicate ``r``: draw the paper's 12 parameters from the study prior (log-normal,
sigma_log ``--prior-sd`` around Table 1; h ~ normal(0, ``--h-sd``); g fixed), one residual
scale [rad] for both angles from the model's ``sigma`` prior
(:data:`heli_uq.probability.priors.SIGMA_PRIOR`), simulate a ``--duration`` s record with
random step inputs (:func:`heli_uq.simulation.synthetic_experiment`) and iid noise, run the
package's NUTS (MAP start, Laplace mass matrix) under the *same* parameter prior, and
record the rank of the true value of every sampled coordinate (the identifiable ratios of
:mod:`heli_uq.probability.coordinates`) among ``--ranks`` thinned draws, and whether the
central 90 % interval covers it.

A failed simulation of a prior draw is redrawn: the model gives such parameters zero
posterior mass (``solver_ok``), so the generating and the inference prior are the same
truncated prior.  The package's model centres the initial-angle prior on the first
measurement; the truth is drawn around the synthetic default start instead.  That makes
the two priors differ whenever the noise sigma is not small next to ``X0_ANGLE_SD``
(0.05 rad; the sigma prior has median 0.05 rad and reaches 2 rad), and it visibly breaks
the ranks of high-noise replicates.  ``--x0-prior generator`` (use it for SBC) gives the
model explicit initial-angle priors ``normal(SYNTHETIC_X0, X0_ANGLE_SD)``
(:meth:`heli_uq.probability.PriorSet.updated`), so the generating and the inference prior
agree; ``data`` keeps the package's data-centred prior.

The generator draws *one* residual scale for both angles, the model has independent
``sigma_theta`` and ``sigma_psi`` priors; the ranked quantities are the model parameters'
coordinates only.

Sampler: the package's ``prepare_start`` (Newton-polished MAP, ``--map-maxiter 0``) and
``run_nuts`` without mass-matrix adaptation (the Laplace covariance kept; add
``--adapt-mass-matrix`` for the package default).  The recorded 60-replicate result
(``studies/results/sbc``) was run before ``run_nuts`` moved to Laplace-whitened
coordinates (when adaptation in raw coordinates collapsed the step size), before the yaw
gains were sampled relative to M22 (the yaw coordinates are now named
``log_<X>_yaw_ratio``), with target acceptance 0.85 (now 0.95) and the chain started at
the MAP (now at a Laplace draw), and before the package was split into one folder per
stage.  It has not been rerun since.

Each replicate is saved to ``--out/rep_XXXX.json`` as it finishes; running again skips
finished replicates (resume).  ``--plot`` draws the rank histograms with the 99 % band of
a uniform rank distribution to ``studies/figures/sbc_ranks.png`` and writes the summary
(``--out/summary.json``).  Each replicate and the summary carry a ``provenance`` entry
(package and JAX versions, command line, wall time [s]).

Usage::

    python studies/sbc.py --replicates 60 --h-sd 0 --chains 1 --warmup 200 --draws 100 \
        --x0-prior generator --out studies/results/sbc
    # two processes on two cores: --shard 0/2 and --shard 1/2 (disjoint replicates)
    python studies/sbc.py --out studies/results/sbc --plot
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys
import tempfile
import time

import jax
import numpy as np
from scipy import stats

from heli_uq.errors import DataFormatError
from heli_uq.figure import new_figure, save_figure
from heli_uq.inference import prepare_start, run_nuts
from heli_uq.io import atomic_write_text
from heli_uq.model import TABLE1, HeliModel, Prior
from heli_uq.probability import PriorSet, make_problem
from heli_uq.probability.priors import SIGMA_PRIOR, X0_ANGLE_SD, X0_RATE_SD
from heli_uq.simulation import SYNTHETIC_X0, synthetic_experiment

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from _study import provenance  # noqa: E402

#: The model of the study: the paper's (12 parameters, no effects).
MODEL = HeliModel()
#: Parameters the study prior leaves at the model's default prior (g is fixed there) or
#: sets separately (h, ``--h-sd``).
NOT_LOGNORMAL = ("g", "h")
#: Initial-state entries whose prior ``--x0-prior generator`` centres on SYNTHETIC_X0.
X0_ANGLES = ("theta0", "psi0")
#: Prior draws tried per replicate before giving up (a draw whose simulation is not
#: finite, or whose angles leave |angle| < MAX_ANGLE [rad], is redrawn).
MAX_REDRAWS = 100
MAX_ANGLE = 50.0


def study_priors(prior_sd: float, h_sd: float, x0_prior: str = "data") -> PriorSet:
    """The study prior: log-normal (sigma_log ``prior_sd``) around Table 1, h ~ normal(0,
    ``h_sd`` [m]) or fixed at 0, g fixed; with ``x0_prior="generator"`` the initial angles'
    prior is ``normal(SYNTHETIC_X0, X0_ANGLE_SD)`` instead of the data-centred default."""
    changes = {n: Prior("lognormal", TABLE1[n], prior_sd) for n in MODEL.names
               if n not in NOT_LOGNORMAL}  # fmt: skip
    changes["h"] = Prior("normal", 0.0, h_sd) if h_sd > 0 else Prior("fixed", 0.0)
    if x0_prior == "generator":
        changes.update({n: Prior("normal", SYNTHETIC_X0[i], X0_ANGLE_SD)
                        for i, n in enumerate(X0_ANGLES)})  # fmt: skip
    return PriorSet.default(MODEL).updated(MODEL, changes, where="sbc prior")


def draw_replicate(r: int, priors: PriorSet, duration: float):
    """Truth and record of replicate ``r`` (redrawn until the simulation is finite)."""
    rng = np.random.default_rng([2026, r])
    for attempt in range(MAX_REDRAWS):
        truth = {n: float(priors.params[n].sample(rng)) for n in MODEL.names}
        sigma = float(SIGMA_PRIOR.sample(rng))
        x0 = np.array(SYNTHETIC_X0) + rng.normal(size=4) * [X0_ANGLE_SD, X0_ANGLE_SD,
                                                           X0_RATE_SD, X0_RATE_SD]
        try:
            rec = synthetic_experiment(truth, x0, duration=duration, noise_std=(sigma, sigma),
                                       seed=int(rng.integers(2**31)), model=MODEL)
        except DataFormatError:
            continue
        if np.all(np.abs(rec.y) < MAX_ANGLE):
            return truth, sigma, x0, rec, attempt
    raise RuntimeError(f"replicate {r}: no finite prior draw in {MAX_REDRAWS} attempts")


def run_replicate(r: int, args, argv=None) -> dict:
    t_rep = time.perf_counter()
    priors = study_priors(args.prior_sd, args.h_sd, args.x0_prior)
    truth, sigma, x0, rec, redraws = draw_replicate(r, priors, args.duration)
    problem = make_problem(rec, model=MODEL, priors=priors, error="iid")
    coords = problem.coords
    z_true = coords.from_physical(truth)
    names = coords.sampled_names
    z_true = z_true[1:] if coords.marginal_scale else z_true
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        start = prepare_start(problem, n_starts=2, seed=r, map_maxiter=args.map_maxiter)
        t1 = time.perf_counter()
        run = run_nuts(problem, tmp, chains=args.chains, warmup=args.warmup, draws=args.draws,
                       seed=r, progress=False, start=start,
                       adapt_mass_matrix=args.adapt_mass_matrix)  # fmt: skip
    wall = time.perf_counter() - t0
    z = run.samples["z"].reshape(-1, len(names))
    thin = max(1, z.shape[0] // args.ranks)
    zt = z[::thin][: args.ranks]
    out = {"replicate": r, "truth": truth, "sigma": sigma, "x0": x0.tolist(), "redraws": redraws,
           "names": list(names), "L": int(zt.shape[0]), "wall_s": wall,
           "divergences": int(np.sum(run.stats["diverging"])),
           "mean_steps": float(np.mean(run.stats["num_steps"])),
           "step_size": run.info["step_size"], "start_s": t1 - t0, "nuts_s": wall - (t1 - t0),
           "map_grad_max": float(start.map_grad_max), "map_decrement": float(start.map_decrement),
           "settings": {k: getattr(args, k) for k in ("duration", "prior_sd", "h_sd", "chains",
                                                     "warmup", "draws", "adapt_mass_matrix",
                                                     "map_maxiter", "x0_prior")},
           "ranks": {}, "covered90": {}}  # fmt: skip
    for i, n in enumerate(names):
        out["ranks"][n] = int(np.sum(zt[:, i] < z_true[i]))
        lo, hi = np.quantile(z[:, i], [0.05, 0.95])
        out["covered90"][n] = bool(lo <= z_true[i] <= hi)
    out["provenance"] = provenance(__file__, argv, time.perf_counter() - t_rep)
    return out


def plot(reps: list, out_png: pathlib.Path, summary_path: pathlib.Path, argv=None):
    t0 = time.perf_counter()
    names = reps[0]["names"]
    big_l = min(r["L"] for r in reps)
    n = len(reps)
    bins = 10
    edges = np.linspace(0, big_l + 1, bins + 1)
    lo, hi = stats.binom.ppf([0.005, 0.995], n, 1 / bins)
    cols = 4
    rows = -(-len(names) // cols)
    fig = new_figure((3.2 * cols, 2.4 * rows))
    axes = fig.subplots(rows, cols, squeeze=False)
    summary = {"replicates": n, "L": big_l, "quantities": {}}
    for ax, name in zip(axes.flat, names):
        ranks = np.array([min(r["ranks"][name], big_l) for r in reps])
        ax.axhspan(lo, hi, color="0.85", label="99 % band (uniform)")
        ax.axhline(n / bins, color="0.5", lw=0.8)
        ax.hist(ranks, bins=edges, color="C0", edgecolor="white", label="rank of truth")
        ax.set_title(name, fontsize=9)
        ax.set_xlabel(f"rank among {big_l} draws")
        ax.set_ylabel("replicates")
        cov = float(np.mean([r["covered90"][name] for r in reps]))
        p = stats.chisquare(np.histogram(ranks, edges)[0]).pvalue
        summary["quantities"][name] = {"coverage90": cov, "chi2_pvalue": float(p)}
        ax.text(0.02, 0.95, f"90% cov {cov:.0%}", transform=ax.transAxes, fontsize=8, va="top")
    for ax in list(axes.flat)[len(names):]:
        ax.axis("off")
    handles, labels = axes.flat[0].get_legend_handles_labels()
    spare = list(axes.flat)[len(names):]
    if spare:
        spare[0].legend(handles, labels, fontsize=8, loc="center")
    else:
        axes.flat[0].legend(fontsize=7, loc="lower left")
    # Coverage split by the noise level: the model centres the initial-angle prior on the
    # first (noisy) measurement, the generator does not, so the two priors differ when
    # sigma is not small next to X0_ANGLE_SD.
    low = [r for r in reps if r["sigma"] < X0_ANGLE_SD]
    high = [r for r in reps if r["sigma"] >= X0_ANGLE_SD]
    for label, group in (("sigma_below_x0_sd", low), ("sigma_above_x0_sd", high)):
        summary[f"coverage90_{label}"] = {
            "replicates": len(group),
            "mean_over_quantities": (float(np.mean([[r["covered90"][q] for q in names]
                                                    for r in group])) if group else None),
        }  # fmt: skip
    summary["coverage90_mean_over_quantities"] = float(
        np.mean([[r["covered90"][q] for q in names] for r in reps]))
    st = reps[0].get("settings", {})
    fig.suptitle(f"SBC: ranks of the true coordinates, {n} synthetic {st.get('duration', '?')} s "
                 f"records (x0 prior: {st.get('x0_prior', 'data')}; grey: 99 % band of "
                 f"uniform ranks)", fontsize=11)  # fmt: skip
    fig.tight_layout()
    out_png.parent.mkdir(parents=True, exist_ok=True)
    save_figure(fig, out_png)
    summary["divergences_total"] = int(sum(r["divergences"] for r in reps))
    summary["mean_steps"] = float(np.mean([r["mean_steps"] for r in reps]))
    summary["wall_s_mean"] = float(np.mean([r["wall_s"] for r in reps]))
    summary["step_size_mean"] = float(np.mean([np.mean(r.get("step_size", np.nan)) for r in reps]))
    summary["map_grad_max_max"] = float(max(r.get("map_grad_max", np.nan) for r in reps))
    summary["settings"] = reps[0].get("settings")
    summary["provenance"] = provenance(__file__, argv, time.perf_counter() - t0)
    atomic_write_text(summary_path, json.dumps(summary, indent=1))
    print(json.dumps(summary, indent=1))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--replicates", type=int, default=60)
    ap.add_argument("--duration", type=float, default=5.0)
    ap.add_argument("--prior-sd", type=float, default=0.1)
    ap.add_argument("--h-sd", type=float, default=0.005, help="prior sd of h [m]; 0 fixes h = 0")
    ap.add_argument("--chains", type=int, default=2)
    ap.add_argument("--warmup", type=int, default=200)
    ap.add_argument("--draws", type=int, default=150)
    ap.add_argument("--map-maxiter", type=int, default=0,
                    help="L-BFGS steps before the Newton polish of the MAP (0: Newton only)")
    ap.add_argument("--x0-prior", choices=("data", "generator"), default="data",
                    help="centre of the initial-angle prior: the first measurement (the "
                         "package's model) or the generator's centre (a consistent SBC)")
    ap.add_argument("--adapt-mass-matrix", action="store_true",
                    help="also adapt the Laplace mass matrix in warm-up (default: keep it)")
    ap.add_argument("--only", type=int, nargs="*", help="run just these replicates")
    ap.add_argument("--shard", default="0/1",
                    help="k/n: run only replicates r with r %% n == k (parallel processes)")
    ap.add_argument("--ranks", type=int, default=99)
    ap.add_argument("--out", default="studies/results/sbc")
    ap.add_argument("--plot", action="store_true")
    ap.add_argument("--fig", default="studies/figures/sbc_ranks.png", help="--plot output")
    args = ap.parse_args(argv)
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    k, n_shards = (int(v) for v in args.shard.split("/"))
    if not args.plot:
        for r in range(args.replicates):
            path = out / f"rep_{r:04d}.json"
            if path.exists() or r % n_shards != k or (args.only and r not in args.only):
                continue
            res = run_replicate(r, args, argv)
            atomic_write_text(path, json.dumps(res))
            # Every replicate compiles new closures (its data are constants of the jitted
            # functions); without this a long run exhausts memory in LLVM compilation.
            jax.clear_caches()
            print(f"replicate {r}: {res['wall_s']:.0f} s, {res['divergences']} divergences, "
                  f"{res['mean_steps']:.0f} steps", flush=True)
    reps = [json.loads(p.read_text()) for p in sorted(out.glob("rep_*.json"))]
    if len({tuple(r["names"]) for r in reps}) > 1:
        sys.exit(f"{out}: the replicates have different coordinates (written by different "
                 "package versions); keep them in separate --out directories")
    if args.plot and reps:
        plot(reps, pathlib.Path(args.fig), out / "summary.json", argv)
    return 0


if __name__ == "__main__":
    sys.exit(main())
