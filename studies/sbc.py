"""Simulation-based calibration (SBC) of the NUTS posterior on short synthetic records.

A thin script over :mod:`heli_uq.calibration.sbc` (read its docstring for what a replicate
is: the study prior, the generator, the sampler, the ranks and the 90 % coverage).  The
replicates are independent tasks of :func:`heli_uq.executor.run_tasks`: ``--scheduler
local`` (default) runs them on a Dask cluster of ``--workers`` processes (default one per
core), ``serial`` one after another in this process, and an address
(``tcp://host:8786``) on an existing Dask scheduler.  Replicate ``r``'s randomness
depends only on ``r`` and the settings, so every scheduler gives the same replicates.

``--x0-prior generator`` (use it for SBC) gives the model the generator's initial-angle
prior; ``data`` keeps the package's data-centred prior, which differs from the
generator's when the noise sigma is not small next to ``X0_ANGLE_SD`` and visibly breaks
the ranks of high-noise replicates.

Each replicate is saved to ``--out/rep_XXXX.json`` as it finishes; running again skips
finished replicates (resume) and retries failed ones (listed in ``--out/failed.json``).
The settings are stored in ``--out/settings.json``; a rerun into the same directory under
other settings is refused.  ``--plot`` (instead of running) draws the rank histograms
with the 99 % band of a uniform rank distribution to ``--fig`` and writes the summary
(``--out/summary.json``, with a ``provenance`` entry: package and JAX versions, command
line, wall time [s]).

The recorded 60-replicate result (``studies/results/sbc``) was run before ``run_nuts``
moved to Laplace-whitened coordinates, before the yaw gains were sampled relative to M22
(the yaw coordinates are now named ``log_<X>_yaw_ratio``), with target acceptance 0.85
(now 0.95) and the chain started at the MAP (now at a Laplace draw); its rerun with the
current package is ``studies/results/sbc_v2``.

Usage::

    python studies/sbc.py --replicates 100 --h-sd 0 --chains 1 --warmup 200 --draws 100 \\
        --x0-prior generator --workers 2 --out studies/results/sbc_v2
    python studies/sbc.py --out studies/results/sbc_v2 --plot
    python studies/sbc.py --replicates 100 --h-sd 0 --chains 1 --warmup 200 --draws 100 \\
        --x0-prior generator --effects yaw:quadratic_drag --out studies/results/sbc_drag_yaw
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys
import time

from heli_uq.calibration import SBCSettings, load_replicates, plot_ranks, run_sbc, summarise
from heli_uq.calibration.sbc import FAILED_FILE
from heli_uq.errors import HeliUQError
from heli_uq.io import atomic_write_text
from heli_uq.log import configure_cli

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from _study import provenance  # noqa: E402


def _settings(args) -> SBCSettings:
    return SBCSettings(duration=args.duration, prior_sd=args.prior_sd, h_sd=args.h_sd,
                       chains=args.chains, warmup=args.warmup, draws=args.draws,
                       adapt_mass_matrix=args.adapt_mass_matrix, map_maxiter=args.map_maxiter,
                       x0_prior=args.x0_prior, ranks=args.ranks,
                       thin_to_ess=not args.no_thin,
                       effects=tuple(e for e in (args.effects or "").split(",") if e))  # fmt: skip


def plot(out: pathlib.Path, fig: pathlib.Path, argv=None) -> dict:
    """Rank histograms to ``fig`` and the summary to ``out/summary.json`` (returned)."""
    t0 = time.perf_counter()
    reps = load_replicates(out)
    if not reps:
        raise HeliUQError(f"{out}: no replicates to plot")
    summary = summarise(reps)
    plot_ranks(reps, fig)
    summary["provenance"] = provenance(__file__, argv, time.perf_counter() - t0)
    atomic_write_text(out / "summary.json", json.dumps(summary, indent=1))
    return summary


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
    ap.add_argument("--effects", default=None, metavar="AXIS:EFFECT,...",
                    help="named effects added to the paper's model, their parameters drawn from "
                         "their declared priors and ranked (e.g. yaw:quadratic_drag)")
    ap.add_argument("--only", type=int, nargs="*", help="run just these replicates")
    ap.add_argument("--ranks", type=int, default=99, help="most draws the truth is ranked among")
    ap.add_argument("--no-thin", action="store_true",
                    help="rank among the draws as they are (default: thinned to their ESS)")
    ap.add_argument("--scheduler", default="local",
                    help="'local' (Dask cluster of --workers processes), 'serial' (in this "
                         "process) or the address of a Dask scheduler (tcp://host:8786)")
    ap.add_argument("--workers", type=int, default=None,
                    help="worker processes of the local cluster (default: one per core)")
    ap.add_argument("--out", default="studies/results/sbc")
    ap.add_argument("--plot", action="store_true", help="plot and summarise instead of running")
    ap.add_argument("--fig", default="studies/figures/sbc_ranks.png", help="--plot output")
    args = ap.parse_args(argv)
    configure_cli(quiet=False)
    out = pathlib.Path(args.out)
    try:
        if args.plot:
            print(json.dumps(plot(out, pathlib.Path(args.fig), argv), indent=1))
            return 0
        wanted = [r for r in range(args.replicates) if not args.only or r in args.only]
        t0 = time.perf_counter()
        reps = run_sbc(out, _settings(args), wanted, scheduler=args.scheduler, workers=args.workers)
        wall = time.perf_counter() - t0
    except HeliUQError as exc:
        print(f"sbc.py: {exc}", file=sys.stderr)
        return 2
    failed = json.loads((out / FAILED_FILE).read_text()) if (out / FAILED_FILE).exists() else {}
    failed = sorted(int(r) for r in failed if int(r) in wanted)
    print(f"{len(reps)}/{len(wanted)} replicates stored in {out} ({wall:.0f} s)"
          + (f"; failed: {failed}" if failed else ""))  # fmt: skip
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
