"""Does a designed input shrink the posterior more than the published profile and random
staircases of the same length, at truths the design did not see?

The design is made by ``heli_uq.design.design`` from the package's default prior
(linearised at a fit of the rig record).  Held-out truths are drawn around that centre
(sd ``--spread`` in every log coordinate); at each truth the linearised (Laplace) posterior
of an experiment is ``(S^-1 + F(truth))^-1`` with ``F`` the whitened Fisher information of
the simulated angles.  Reported per truth: the posterior volume of the design relative to
the published profile (its first ``--duration`` seconds) and to the median of ``--random``
random staircases; the directions no input identifies (the common scale) cancel in these
ratios, so they are ratios over the identifiable combinations.

One JSON line per run goes to ``studies/results/design_gain.jsonl``; the design's figure
is copied to ``studies/figures/design_<duration>s.png``.  Usage::

    python studies/design_gain.py [--duration 60] [--truths 5] [--random 20] [--budget quick]
"""

from __future__ import annotations

import argparse
import dataclasses
import pathlib
import shutil
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from _study import FIGURES, RESULTS, append_jsonl, provenance  # noqa: E402

from heli_uq.data import load_data  # noqa: E402
from heli_uq.design import DesignPrior, InformationGain, StaircaseBounds, design  # noqa: E402
from heli_uq.design.staircase import random_staircase  # noqa: E402


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=60.0)
    parser.add_argument("--truths", type=int, default=5)
    parser.add_argument("--spread", type=float, default=0.1, help="sd of the truths in w")
    parser.add_argument("--random", type=int, default=20)
    parser.add_argument("--budget", default="quick", choices=["quick", "full"])
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    t0 = time.perf_counter()
    bounds = StaircaseBounds(args.duration)
    prior = DesignPrior.default(dt=bounds.dt, seed=args.seed)
    published = load_data("experimental")
    with tempfile.TemporaryDirectory() as tmp:
        summary = design(tmp, bounds, prior=prior, published=published, budget=args.budget,
                         seed=args.seed, log=print)  # fmt: skip
        FIGURES.mkdir(parents=True, exist_ok=True)
        shutil.copy(pathlib.Path(tmp) / "design.png", FIGURES / f"design_{args.duration:g}s.png")
        u_design = load_data(str(pathlib.Path(tmp) / "design.csv")).u
    rng = np.random.default_rng(args.seed + 1)
    inputs = {"design": u_design, "published": published.u[: bounds.n]}
    randoms = [random_staircase(bounds, rng).inputs() for _ in range(args.random)]
    rows = []
    for i in range(args.truths):
        truth = prior.center + args.spread * rng.standard_normal(prior.center.shape)
        gain = InformationGain(dataclasses.replace(prior, draws=truth[None, :]), bounds.dt)
        eig = {k: gain.value(u) for k, u in inputs.items()}
        rand = np.array([gain.value(u) for u in randoms])
        eig["random_median"] = float(np.median(rand[np.isfinite(rand)]))
        # posterior volume ratio = exp(-(EIG_design - EIG_other)) at this truth
        rows.append({"truth": i, "eig": eig,
                     "volume_ratio_vs_published": float(np.exp(eig["published"] - eig["design"])),
                     "volume_ratio_vs_random_median": float(np.exp(eig["random_median"] - eig["design"])),
                     "random_beaten": float(np.mean(rand < eig["design"]))})  # fmt: skip
        print(f"truth {i}: EIG design {eig['design']:.2f}, published {eig['published']:.2f}, "
              f"random median {eig['random_median']:.2f} nats; volume ratio vs published "
              f"{rows[-1]['volume_ratio_vs_published']:.3g}, vs random median "
              f"{rows[-1]['volume_ratio_vs_random_median']:.3g}")  # fmt: skip
    row = {"study": "design_gain", "duration_s": args.duration, "spread": args.spread,
           "design_value": summary["value"], "design_seconds": summary["seconds"],
           "published_value": summary["baselines"]["published"]["value"],
           "random_median_value": summary["baselines"]["random"]["median"], "truths": rows,
           **provenance(__file__, argv, time.perf_counter() - t0)}  # fmt: skip
    print(f"wrote {append_jsonl(RESULTS / 'design_gain.jsonl', row)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
