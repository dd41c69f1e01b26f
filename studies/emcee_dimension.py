"""How far emcee scales: its autocorrelation time against the posterior's dimension.

emcee's stretch move is affine invariant, which makes it good on the mechanistic
posterior's narrow, tilted ridges, but its autocorrelation time grows with the dimension
(Huijser, Goodman & Brewer 2015), and a network adds a dimension per weight.  This study
runs one ensemble per model on the same record (a synthetic rig-like record with a
hidden yaw thrust ``0.05 u_psi |u_psi|`` N m, the one of ``tests/test_hybrid_posterior.py``)
and on the same budget of steps: the mechanistic model, then a neural torque of ``u`` on
yaw with 2 and 4 hidden units.  Per model it appends one JSON line to
``results/emcee_dimension.jsonl``: the dimension, the walkers (``2 d + 2``), the largest
integrated autocorrelation time ``tau_max`` [steps] (emcee's estimate), the steps emcee
asks for (``50 tau_max``), the evaluations that makes (times the walkers), the measured
time per step and the wall time those steps would take.
:data:`heli_uq.inference.emcee_sampler.MAX_DIM` is set from these numbers.

Usage: ``python studies/emcee_dimension.py [--seconds 20] [--steps 3000]``.
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import tempfile
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from _study import RESULTS, append_jsonl, provenance  # noqa: E402

#: The hidden yaw thrust [N m / V^2] and the record's seed (as in tests/test_hybrid_posterior.py).
HIDDEN_THRUST = 0.05
RECORD_SEED = 5
MODELS = {"mechanistic": [],
          "FNN(u) h=2": [{"effect": "neural_torque", "axis": "yaw", "inputs": "u", "hidden": 2}],
          "FNN(u) h=4": [{"effect": "neural_torque", "axis": "yaw", "inputs": "u", "hidden": 4}]}  # fmt: skip


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--steps", type=int, default=3000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=str(RESULTS / "emcee_dimension.jsonl"))
    args = ap.parse_args(argv)
    import numpy as np

    from heli_uq.inference import prepare_start, run_emcee
    from heli_uq.inference.emcee_sampler import TAU_FACTOR
    from heli_uq.model import RIG_FIT, RIG_FIT_X0, build_model
    from heli_uq.probability import make_problem
    from heli_uq.simulation import synthetic_experiment

    truth = {**RIG_FIT, "k_q_yaw": HIDDEN_THRUST}
    record = synthetic_experiment(truth, RIG_FIT_X0, duration=args.seconds, inputs="steps",
                                  noise_std=(0.003, 0.008), seed=RECORD_SEED,
                                  model=build_model(["yaw:quadratic_thrust"]))  # fmt: skip
    for name, effects in MODELS.items():
        t0 = time.perf_counter()
        problem = make_problem(record, model=build_model(effects), error="iid")
        start = prepare_start(problem, seed=args.seed, guesses=(RIG_FIT,))
        with tempfile.TemporaryDirectory() as tmp:
            run = run_emcee(start.problem, tmp, ensembles=1, steps=args.steps, seed=args.seed,
                            progress=False, start=start)  # fmt: skip
        info = run.info
        tau = np.asarray(info["tau"][0])
        tau_max = float(np.max(tau))
        per_step = info["wall_seconds"] / args.steps
        line = {"model": name, "seconds_record": args.seconds, "dim": int(start.density.dim),
                "walkers": info["walkers"], "steps": args.steps, "tau_max": tau_max,
                "tau_median": float(np.median(tau)), "acceptance": info["acceptance"][0],
                "steps_needed": TAU_FACTOR * tau_max,
                "evaluations_needed": TAU_FACTOR * tau_max * info["walkers"],
                "seconds_per_step": per_step, "seconds_needed": TAU_FACTOR * tau_max * per_step,
                "trusted": args.steps - info["burn"] >= TAU_FACTOR * tau_max}  # fmt: skip
        line["provenance"] = provenance(__file__, argv, time.perf_counter() - t0)
        append_jsonl(args.out, line)
        print(f"{name}: d = {line['dim']}, tau_max {tau_max:.0f} steps (median {line['tau_median']:.0f}), "
              f"acceptance {line['acceptance']:.2f}, 50 tau = {line['steps_needed']:.0f} steps x "
              f"{line['walkers']} walkers = {line['seconds_needed'] / 60:.1f} min", flush=True)  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
