"""Does projecting the linear physics out of a network of the states help its posterior?

A synthetic record with a known state-dependent torque on yaw (a quadratic drag
``-c omega_psi |omega_psi|``, hidden from the model) under random voltage steps, split
60 / 40 into a training and a test window.  For each projection of the FNN(u, x, v) on yaw
(``none``: the raw network; ``u``: orthogonal to the gains' voltages and the yaw rate over
the training window, :mod:`heli_uq.model.terms.neural_torque`), NUTS over every weight and
the physics (every inertia free unless ``--fix-mass``):

* R-hat (worst variable; the network's torque on its grid included), divergences, the
  share of draws at the tree-depth limit;
* yaw RMSE and 90 % coverage on the test window;
* the trade-off of the yaw gains and damping with the network's linear part
  (:func:`heli_uq.output.network.gain_trade_off`: correlation, and the gain's sd against
  the sd of the sum the data fix).

One JSON line per posterior goes to ``--out`` (default
``studies/results/hybrid_state_network.jsonl``).  Usage::

    python studies/hybrid_state_network.py [--seconds 24] [--seed 1] [--projections none u]
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from _study import add_run_arguments, record_line  # noqa: E402

#: The hidden yaw drag [N m s^2/rad^2] (yaw rates of 0.2-1 rad/s: 0.004-0.1 N m).
DRAG = 0.1
#: Fraction of the record in the training window.
TRAIN_FRACTION = 0.6
#: NUTS target acceptance (the hybrid rig runs' value).
TARGET_ACCEPT = 0.95


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=24.0)
    ap.add_argument("--record-seed", type=int, default=5, help="seed of the record's voltage steps and noise")
    ap.add_argument("--seed", type=int, default=1, help="seed of the sampler")
    ap.add_argument("--hidden", type=int, default=2)
    ap.add_argument("--projections", nargs="+", default=["none", "u"], choices=["none", "u", "1,u"])
    ap.add_argument("--fix-mass", action="store_true", help="fix m at the truth (plain log coordinates)")
    add_run_arguments(ap, "hybrid_state_network", chains=2, warmup=200, draws=200)
    args = ap.parse_args(argv)

    import numpyro

    numpyro.set_host_device_count(args.chains)
    from heli_uq.model import RIG_FIT, RIG_FIT_X0, build_model
    from heli_uq.model.prior import Prior
    from heli_uq.output import sample_posterior
    from heli_uq.probability import PriorSet
    from heli_uq.simulation import synthetic_experiment

    truth = build_model(["yaw:quadratic_drag"])
    values = {**RIG_FIT, "c_yaw": DRAG}
    record = synthetic_experiment(values, RIG_FIT_X0, duration=args.seconds, inputs="steps",
                                  seed=args.record_seed, noise_std=(0.003, 0.008), model=truth)  # fmt: skip
    cut = round(TRAIN_FRACTION * args.seconds, 2)
    train, test = (0.0, cut), (cut, args.seconds)
    for project in args.projections:
        model = build_model([{"effect": "neural_torque", "axis": "yaw", "inputs": "u,x,v",
                              "hidden": args.hidden, "project": project}])  # fmt: skip
        priors = PriorSet.default(model)
        if args.fix_mass:
            priors = priors.updated(model, {"m": Prior("fixed", values["m"])})
        t0 = time.perf_counter()
        print(f"project={project}: NUTS {args.chains} x ({args.warmup} + {args.draws})", flush=True)
        _, summary = sample_posterior(record, pathlib.Path(args.runs) / f"{project}_seed{args.seed}",
                                      model=model, train=train, test=test, priors=priors, error="iid",
                                      chains=args.chains, warmup=args.warmup, draws=args.draws,
                                      target_accept=TARGET_ACCEPT, seed=args.seed,
                                      progress=False)  # fmt: skip
        te = summary["windows"]["test"]
        line = {"project": project, "fix_mass": args.fix_mass, "seconds_record": args.seconds,
                "record_seed": args.record_seed, "seed": args.seed, "hidden": args.hidden,
                "drag": DRAG, "train": list(train), "test": list(test),
                "chains": args.chains, "warmup": args.warmup, "draws": args.draws,
                "rhat_max": summary.get("rhat_max"),
                "worst_rhat_variable": summary.get("worst_rhat_variable"),
                "rhat_max_network_torque": summary.get("rhat_max_network_torque"),
                "divergences": summary.get("divergences"),
                "tree_depth_saturation": summary.get("tree_depth_saturation"),
                "test_rmse_psi": te["rmse"]["psi"], "test_coverage90_psi": te["coverage90"]["psi"],
                "trade_off": summary.get("gain_trade_off", {}).get("yaw"),
                "health": summary["health"]["flags"], "seconds": time.perf_counter() - t0}  # fmt: skip
        record_line(__file__, argv, args.out, line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
