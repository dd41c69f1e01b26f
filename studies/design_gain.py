"""Does a designed input shrink the posterior more than the published profile and random
staircases of the same length, at truths the design did not see?

The design is made by ``heli_uq.design.design`` from the package's default prior
(linearised at a fit of the rig record).  Held-out truths are drawn around that centre
(sd ``--spread`` in every log coordinate); a truth is kept only when the published profile
keeps its pitch within +-90 deg (the rig did not flip on it); at each truth the linearised (Laplace) posterior
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

#: Truths drawn per kept truth before giving up (a truth is kept when the published
#: profile keeps its pitch within +-90 deg, as the rig did).
MAX_REJECTED = 20


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
    rows, rejected = [], 0
    while len(rows) < args.truths:
        if rejected > MAX_REJECTED * args.truths:
            raise SystemExit(f"design_gain: only {len(rows)} of {rejected + len(rows)} truths keep the "
                             "published profile's pitch within +-90 deg; lower --spread")
        truth = prior.center + args.spread * rng.standard_normal(prior.center.shape)
        # The physical range (+-90 deg), not the design's envelope: a truth counts when the
        # rig would not flip on the published profile (it did not), and a design that flips
        # the arm at such a truth is reported as infeasible there.
        gain = InformationGain(dataclasses.replace(prior, draws=truth[None, :]), bounds.dt)
        eig = {k: gain.value(u) for k, u in inputs.items()}
        if not np.isfinite(eig["published"]):
            rejected += 1
            continue
        rand = np.array([gain.value(u) for u in randoms])
        eig["random_median"] = float(np.median(rand))  # an infeasible staircase counts as -inf
        i = len(rows)
        # posterior volume ratio = exp(-(EIG_design - EIG_other)) at this truth
        rows.append({"truth": i, "eig": eig, "design_feasible": bool(np.isfinite(eig["design"])),
                     "random_feasible": float(np.mean(np.isfinite(rand))),
                     "volume_ratio_vs_published": float(np.exp(eig["published"] - eig["design"])),
                     "volume_ratio_vs_random_median": float(np.exp(eig["random_median"] - eig["design"])),
                     "random_beaten": float(np.mean(rand < eig["design"]))})  # fmt: skip
        print(f"truth {i}: EIG design {eig['design']:.2f}, published {eig['published']:.2f}, "
              f"random median {eig['random_median']:.2f} nats; volume ratio vs published "
              f"{rows[-1]['volume_ratio_vs_published']:.3g}, vs random median "
              f"{rows[-1]['volume_ratio_vs_random_median']:.3g}")  # fmt: skip
    ratios = np.array([r["volume_ratio_vs_published"] for r in rows])
    row = {"study": "design_gain", "duration_s": args.duration, "spread": args.spread,
           "design_value": summary["value"], "design_seconds": summary["seconds"],
           "published_value": summary["baselines"]["published"]["value"],
           "random_median_value": summary["baselines"]["random"]["median"], "truths": rows,
           "truths_rejected": rejected, "pitch_envelope_deg": [float(np.degrees(v)) for v in bounds.pitch],
           "median_volume_ratio_vs_published": float(np.median(ratios)),
           "design_feasible_fraction": float(np.mean([r["design_feasible"] for r in rows])),
           **provenance(__file__, argv, time.perf_counter() - t0)}  # fmt: skip
    print(f"wrote {append_jsonl(RESULTS / 'design_gain.jsonl', row)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
