"""Does projecting the linear physics out of a network of the states help its posterior,
and can the effect it learned be named?

A synthetic record with a known state-dependent torque on yaw (``--hidden-effect``, at its
value in ``discovery_confusion.HIDDEN``; default a quadratic drag ``-c omega_psi
|omega_psi|``, hidden from the model) under random voltage steps, split 60 / 40 into a
training and a test window.  For each projection of the FNN(u, x, v) on yaw
(``none``: the raw network; ``u``: orthogonal to the gains' voltages and the yaw rate over
the training window, :mod:`heli_uq.model.terms.neural_torque`), NUTS over every weight and
the physics (every inertia free unless ``--fix-mass``):

* R-hat (worst variable; the network's torque on its grid included), divergences, the
  share of draws at the tree-depth limit;
* yaw RMSE and 90 % coverage on the test window;
* the trade-off of the yaw gains and damping with the network's linear part
  (:func:`heli_uq.output.network.gain_trade_off`: correlation, and the gain's sd against
  the sd of the sum the data fix);
* with ``--name-effects``: the effects of the table the network's torque is made of
  (:func:`heli_uq.discovery.network_effects.network_effects_of`: inclusion probabilities,
  the selected effects), and, if any, the model with those effects in place of the
  network refitted by NUTS (test yaw RMSE and coverage, the hidden values' 95 % intervals);
* with ``--check-named`` (implies ``--name-effects``): before the refit the named effects
  (or, if none is named, the credible ones that explain too little to be named) are
  checked on held-out blocks of the training window by ``discover`` restricted to them
  (:func:`heli_uq.discovery.network_check.check_candidates`; needs a training window of
  at least 20 s, e.g. ``--seconds 40``), and only what it adds is refitted.

One JSON line per posterior goes to ``--out`` (default
``studies/results/hybrid_state_network.jsonl``).  Usage::

    python studies/hybrid_state_network.py [--seconds 24] [--seed 1] [--projections none u]
    python studies/hybrid_state_network.py --hidden-effect yaw:torsional_spring --projections u --name-effects
    python studies/hybrid_state_network.py --hidden-effect yaw:coulomb_friction --record-seed 6 \
        --seconds 40 --projections u --check-named
    python studies/hybrid_state_network.py --posterior out/hybrid_uxv/posterior.nc
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from _study import add_run_arguments, record_line  # noqa: E402
from discovery_confusion import HIDDEN  # noqa: E402  (the confusion study's hidden values)

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
    ap.add_argument("--hidden-effect", default="yaw:quadratic_drag",
                    help="axis:effect hidden in the record, at its value in discovery_confusion.HIDDEN")
    ap.add_argument("--name-effects", action="store_true",
                    help="name the network's torque by the effects table and refit the named model")
    ap.add_argument("--check-named", action="store_true",
                    help="check the named effects by discover on the training window before the refit")
    ap.add_argument("--posterior", nargs="+", metavar="POSTERIOR_NC",
                    help="only name the effects of stored posteriors of a network of the states (e.g. the "
                         "rig's, from heli-uq sample --model hybrid --nn-inputs u,x,v)")
    add_run_arguments(ap, "hybrid_state_network", chains=2, warmup=200, draws=200)
    args = ap.parse_args(argv)

    import numpyro

    numpyro.set_host_device_count(args.chains)
    from heli_uq.model import RIG_FIT, RIG_FIT_X0, build_model
    from heli_uq.model.prior import Prior
    from heli_uq.output import sample_posterior
    from heli_uq.probability import PriorSet
    from heli_uq.simulation import synthetic_experiment

    if args.posterior:
        return _name_stored(args, argv)
    truth = build_model([args.hidden_effect])
    axis, kind = args.hidden_effect.split(":")
    hidden = {f"{name}_{axis}": value for name, value in HIDDEN[axis][kind].items()}
    values = {**RIG_FIT, **hidden}
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
        tag = "" if args.hidden_effect == "yaw:quadratic_drag" else f"_{kind}"
        run_dir = pathlib.Path(args.runs) / f"{project}_seed{args.seed}{tag}"
        idata, summary = sample_posterior(record, run_dir,
                                      model=model, train=train, test=test, priors=priors, error="iid",
                                      chains=args.chains, warmup=args.warmup, draws=args.draws,
                                      target_accept=TARGET_ACCEPT, seed=args.seed,
                                      progress=False)  # fmt: skip
        te = summary["windows"]["test"]
        line = {"project": project, "fix_mass": args.fix_mass, "seconds_record": args.seconds,
                "record_seed": args.record_seed, "seed": args.seed, "hidden": args.hidden,
                "hidden_effect": args.hidden_effect, "hidden_values": hidden,
                "train": list(train), "test": list(test),
                "chains": args.chains, "warmup": args.warmup, "draws": args.draws,
                "rhat_max": summary.get("rhat_max"),
                "worst_rhat_variable": summary.get("worst_rhat_variable"),
                "rhat_max_network_torque": summary.get("rhat_max_network_torque"),
                "divergences": summary.get("divergences"),
                "tree_depth_saturation": summary.get("tree_depth_saturation"),
                "test_rmse_psi": te["rmse"]["psi"], "test_coverage90_psi": te["coverage90"]["psi"],
                "trade_off": summary.get("gain_trade_off", {}).get("yaw"),
                "health": summary["health"]["flags"], "seconds": time.perf_counter() - t0}  # fmt: skip
        if args.name_effects or args.check_named:
            line["named"] = _name_and_refit(args, record, train, test, priors, idata, run_dir, hidden, tag)
            line["seconds"] = time.perf_counter() - t0
        record_line(__file__, argv, args.out, line)
    return 0


def _name_stored(args, argv) -> int:
    """One line per stored posterior: the effects its network of the states is made of."""
    from heli_uq.discovery.network_effects import network_effects_of
    from heli_uq.output.inference_data import load_posterior

    for path in args.posterior:
        t0 = time.perf_counter()
        idata, model = load_posterior(path)
        named = network_effects_of(idata, model, "yaw")
        record_line(__file__, argv, args.out, {"posterior": str(path), "model": model.label, "named": named,
                                               "seconds": time.perf_counter() - t0})  # fmt: skip
    return 0


def _check(args, record, train, named, run_dir) -> dict:
    """``discover`` on the training window, restricted to the named effects and their ties:
    what it adds, its candidates' held-out scores and its decision (or why it cannot run:
    the named effects are then refitted unchecked)."""
    from heli_uq.discovery import discover
    from heli_uq.discovery.network_check import check_candidates
    from heli_uq.errors import ParameterError

    candidates = check_candidates({"yaw": named})
    t0 = time.perf_counter()
    try:
        result = discover(record, run_dir / "check", window=train, candidates=candidates,
                          max_effects=len(candidates), seed=args.seed, budget="quick")  # fmt: skip
    except ParameterError as exc:
        return {"candidates": candidates, "error": str(exc)}
    return {"candidates": candidates, "added": result["added"], "decision": result["decision"],
            "scores": [{k: c.get(k) for k in ("effect", "axis", "score", "score_se")}
                       for c in result["candidates"]],
            "seconds": time.perf_counter() - t0}  # fmt: skip


def _name_and_refit(args, record, train, test, priors, idata, run_dir, hidden, tag) -> dict:
    """The effects the network's torque is made of and, if any, the named model's NUTS
    refit in the network's place: its test yaw fit and the hidden values' 95 % intervals."""
    import numpy as np

    from heli_uq.discovery.network_check import check_candidates
    from heli_uq.discovery.network_effects import network_effects_of
    from heli_uq.discovery.network_equation import equation_model
    from heli_uq.output import sample_posterior
    from heli_uq.output.inference_data import load_posterior
    from heli_uq.probability import PriorSet

    _, model = load_posterior(run_dir / "posterior.nc")  # the model as adapted to the record
    named = network_effects_of(idata, model, "yaw")
    print(f"named: {named['selected']} (inclusion {named['inclusion']})", flush=True)
    kept = named["selected"]
    if args.check_named and check_candidates({"yaw": named}):  # named, or credible and too small
        named["check"] = _check(args, record, train, named, run_dir)
        if "error" in named["check"]:  # e.g. a training window too short for discover
            print(f"no held-out check: {named['check']['error']}", flush=True)
        else:
            kept = [a["effect"] for a in named["check"]["added"]]
            print(f"kept by the held-out check: {kept}", flush=True)
    if not kept:
        return named
    refit = equation_model(model, "yaw", kept)
    fixed = {n: p for n, p in priors.params.items() if p.kind == "fixed" and n in refit.names}
    refit_priors = PriorSet.default(refit).updated(refit, fixed) if fixed else PriorSet.default(refit)
    post, rs = sample_posterior(record, pathlib.Path(args.runs) / f"named_seed{args.seed}{tag}", model=refit,
                                train=train, test=test, priors=refit_priors, error="iid", chains=args.chains,
                                warmup=args.warmup, draws=args.draws, target_accept=TARGET_ACCEPT,
                                seed=args.seed, progress=False)  # fmt: skip
    te = rs["windows"]["test"]
    intervals = {n: [float(q) for q in np.quantile(np.asarray(post.posterior[n]), [0.025, 0.975])]
                 for n in hidden if n in post.posterior}  # fmt: skip
    named["refit"] = {"model": refit.label, "rhat_max": rs.get("rhat_max"),
                      "divergences": rs.get("divergences"), "test_rmse_psi": te["rmse"]["psi"],
                      "test_coverage90_psi": te["coverage90"]["psi"], "ci95": intervals,
                      "holds_truth": {n: lo <= hidden[n] <= hi for n, (lo, hi) in intervals.items()},
                      "health": rs["health"]["flags"]}  # fmt: skip
    return named


if __name__ == "__main__":
    sys.exit(main())
