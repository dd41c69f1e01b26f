"""Does a hybrid posterior's band widen at voltage pairs the training window never holds?

A synthetic record with a known input nonlinearity on yaw (a quadratic thrust
``k_q u_psi |u_psi|``, hidden from the model) under random voltage steps (many distinct
pairs), split so that the test window holds pairs the training window does not.  The mass ``m`` is
fixed at the truth; the angles still fix a torque only relative to the yaw inertia, so
torques are compared as angular accelerations (each draw's over its ``M22``,
:func:`heli_uq.output.network.axis_inertia`; the truth's over the true ``M22``).  For each
network posterior (``--nn-posterior full`` samples every weight, ``last-layer``
fixes the trained hidden layer), FNN(u) on yaw:

* the median width of the central 90 % band of the network's acceleration at the training
  pairs and at the unseen pairs, and their ratio (:func:`heli_uq.output.network.band_widths`);
* the fraction of pairs, seen and unseen, whose true acceleration lies inside that band.  The
  truth is the hidden thrust with its part along the gains removed (the weighted
  least-squares fit on ``(u_theta, u_psi)`` over the training pairs, the network's
  projection), so it is what the projected network can hold;
* yaw RMSE and 90 % coverage on the test window, R-hat and the wall time.

``--posteriors gp`` runs the Gaussian-process torque of the voltages instead of a network
(:mod:`heli_uq.model.terms.gp_torque`, every inertia free: its values at the test
window's new pairs are the GP's conditional, sampled with the rest), and ``none`` the
model without any added torque; for these only the test-window numbers, R-hat and health
are reported.

One JSON line per posterior goes to ``--out`` (default
``studies/results/hybrid_unseen_pairs.jsonl``); the network torque figures to
``figures/hybrid_unseen_<posterior>.png``.  Usage::

    python studies/hybrid_unseen_pairs.py [--seconds 40] [--posteriors full last-layer]
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import time

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from _study import add_run_arguments, record_line  # noqa: E402

#: The hidden yaw thrust [N m/V^2] (as in ``tests/test_hybrid_posterior.py``).
K_Q = 0.05
#: Fraction of the record in the training window.
TRAIN_FRACTION = 0.6


def _inside(accel: np.ndarray, truth: np.ndarray) -> float:
    """Fraction of grid points whose ``truth`` (k,) lies in the central 90 % of ``accel`` (S, k)."""
    lo, hi = np.quantile(accel, [0.05, 0.95], axis=0)
    return float(np.mean((lo <= truth) & (truth <= hi)))


def _projected_truth(term, params, pairs: np.ndarray, train_u: np.ndarray) -> np.ndarray:
    """The hidden thrust at ``pairs`` [N m] less its weighted fit on ``(u_theta, u_psi)``
    over the training window's pairs (weights: samples held)."""
    import jax.numpy as jnp

    def thrust(at):
        return np.array([float(term(params, jnp.zeros(2), jnp.zeros(2), jnp.asarray(q))[1]) for q in at])

    seen, counts = np.unique(train_u, axis=0, return_counts=True)
    root_w = np.sqrt(counts / counts.sum())
    beta = np.linalg.lstsq(root_w[:, None] * seen, root_w * thrust(seen), rcond=None)[0]
    return thrust(pairs) - pairs @ beta


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=40.0)
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--hidden", type=int, default=4)
    ap.add_argument("--posteriors", nargs="+", default=["full", "last-layer"],
                    choices=["full", "last-layer", "gp", "none"])
    add_run_arguments(ap, "hybrid_unseen_pairs", chains=2, warmup=250, draws=250)
    args = ap.parse_args(argv)

    import numpyro

    numpyro.set_host_device_count(args.chains)
    from heli_uq.model import RIG_FIT, RIG_FIT_X0, build_model
    from heli_uq.model.prior import Prior
    from heli_uq.model.terms.rigid_body import yaw_inertia
    from heli_uq.output import sample_posterior
    from heli_uq.output.network import UNSEEN, axis_inertia, band_widths
    from heli_uq.output.network_plot import plot_network_torque
    from heli_uq.probability import PriorSet
    from heli_uq.simulation import synthetic_experiment

    truth_model = build_model([{"effect": "quadratic_thrust", "axis": "yaw"}])
    values = {**RIG_FIT, "k_q_yaw": K_Q}
    record = synthetic_experiment(values, RIG_FIT_X0, duration=args.seconds, inputs="steps", seed=args.seed,
                                  noise_std=(0.003, 0.008), model=truth_model)  # fmt: skip
    cut = round(TRAIN_FRACTION * args.seconds, 2)
    train, test = (0.0, cut), (cut, args.seconds)
    n_train = int(np.searchsorted(np.asarray(record.t), cut - 1e-9))
    term, params = truth_model.effects[0], truth_model.complete(values)
    model = build_model([{"effect": "neural_torque", "axis": "yaw", "inputs": "u", "hidden": args.hidden}])
    priors = PriorSet.default(model).updated(model, {"m": Prior("fixed", values["m"])})
    for posterior in args.posteriors:
        t0 = time.perf_counter()
        print(f"{posterior}: NUTS {args.chains} x ({args.warmup} + {args.draws})", flush=True)
        run_dir = pathlib.Path(args.runs) / posterior
        if posterior in ("gp", "none"):
            other = build_model([{"effect": "gp_torque", "axis": "yaw"}] if posterior == "gp" else [])
            _, summary = sample_posterior(record, run_dir, model=other, train=train, test=test, error="iid",
                                          chains=args.chains, warmup=args.warmup, draws=args.draws,
                                          progress=False)  # fmt: skip
            te = summary["windows"]["test"]
            line = {"posterior": posterior, "seconds_record": args.seconds, "train": list(train),
                    "test": list(test), "k_q": K_Q, "test_rmse_psi": te["rmse"]["psi"],
                    "test_coverage90_psi": te["coverage90"]["psi"],
                    "train_rmse_psi": summary["windows"]["train"]["rmse"]["psi"],
                    "gp_tau_yaw": summary["parameters"].get("gp_tau_yaw"),
                    "rhat_max": summary.get("rhat_max"),
                    "worst_rhat_variable": summary.get("worst_rhat_variable"),
                    "tree_depth_saturation": summary.get("tree_depth_saturation"),
                    "health": summary["health"]["flags"], "seconds": time.perf_counter() - t0}  # fmt: skip
            record_line(__file__, argv, args.out, line)
            continue
        idata, summary = sample_posterior(record, run_dir, model=model, train=train, priors=priors,
                                          test=test, error="iid", network_posterior=posterior,
                                          chains=args.chains, warmup=args.warmup, draws=args.draws,
                                          progress=False)  # fmt: skip
        post = idata.posterior
        inertia = axis_inertia(idata, "yaw")[:, None]
        true_inertia = float(yaw_inertia(values, float(np.median(np.asarray(record.y)[:n_train, 0]))))
        inside = {}
        for key, suffix in (("seen", ""), ("unseen", UNSEEN)):
            dim = f"nn_point_yaw{suffix}"
            if f"{dim}_u_psi" not in post.coords:
                continue
            pairs = np.stack([np.asarray(post[f"{dim}_u_theta"]), np.asarray(post[f"{dim}_u_psi"])], axis=1)
            truth = _projected_truth(term, params, pairs, np.asarray(record.u)[:n_train]) / true_inertia
            accel = np.asarray(post[f"nn_torque_yaw{suffix}"]).reshape(-1, len(pairs)) / inertia
            inside[key] = _inside(accel, truth)
        plot_network_torque(idata, "yaw", pathlib.Path(args.figures) / f"hybrid_unseen_{posterior}.png")
        te = summary["windows"]["test"]
        line = {"posterior": posterior, "seconds_record": args.seconds, "train": list(train),
                "test": list(test), "k_q": K_Q, "hidden": args.hidden,
                "band_widths": band_widths(idata, "yaw"),
                "truth_inside_90": inside, "test_rmse_psi": te["rmse"]["psi"],
                "test_coverage90_psi": te["coverage90"]["psi"], "rhat_max": summary.get("rhat_max"),
                "rhat_max_network_torque": summary.get("rhat_max_network_torque"),
                "health": summary["health"]["flags"], "seconds": time.perf_counter() - t0}  # fmt: skip
        record_line(__file__, argv, args.out, line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
