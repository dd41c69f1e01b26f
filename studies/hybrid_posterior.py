"""Bayesian hybrid models on the rig record: the comparison table of issue 11.

Rows, each a NUTS posterior (``heli_uq.output.sample_posterior``, iid errors) on the
training window, predicted over the test window:

* ``mechanistic``: the paper's model;
* ``+ <effect>``: the model with the effects ``heli-uq discover`` added on the rig record
  (``--effect AXIS:EFFECT[,...]``; default: those in ``results/discover_rig/discovery.json``);
* ``+ FNN(u)``, ``+ FNN(u,x,v)``: a neural torque on yaw (``--hidden`` units);
* ``+ recovered equation``: pysindy on the FNN(u) posterior's network torque
  (:func:`heli_uq.discovery.network_equation.recover_equation`), the network replaced by a
  feature torque of the selected features and refitted.

Columns: V of the posterior-mean simulation on the whole record [rad^2], RMSE per angle
and 90 % coverage on train and test, the test window's log predictive density summed over
input segments with its difference to the mechanistic row and that difference's standard
error (:mod:`heli_uq.discovery.score`), the number of sampled parameters, R-hat (physical
parameters and network torque; the raw weights' separately) and the wall time.  One JSON
line per row goes to ``results/hybrid_posterior.jsonl``; the table to
``results/hybrid_posterior.md``; the posteriors to ``--runs`` (git ignores them); the
FNN(u) bands and network torque to ``figures/``.  A network's posterior over every weight
(``--nn-posterior full``) is labelled ``, every weight`` and kept in its own run directory
and figure, beside the last-layer ones.

``--fix NAME=VALUE``, ``--prior`` and ``--priors`` change every row's priors as in ``heli-uq
sample`` (a row so run is labelled with them and kept in its own run directory);
``--time-limit MINUTES`` stops each row's NUTS with the draws made (flagged).

Usage: ``python studies/hybrid_posterior.py [--train 0:91 --test 91:131] [--rows ...]
[--hidden 1 --fix psi0=0.8173 --fix omega_psi0=0 --time-limit 45]``.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import re
import sys
import time

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from _study import RESULTS, add_run_arguments, append_jsonl, provenance  # noqa: E402

from heli_uq.cli.options import add_prior_options, priors_from_args  # noqa: E402

ROWS = ("mechanistic", "effect", "u", "u,x,v", "equation")
#: Hidden units of the stored network rows; another size is labelled with it.
HIDDEN = 4


def _parse_window(text):
    from heli_uq.data import parse_window

    return parse_window(text)


def _discovered_effect(path: pathlib.Path):
    """The effects a discovery run added (``"axis:effect,..."``: a pair added in one step
    is both), or None."""
    if not path.exists():
        return None
    found = json.loads(path.read_text())
    if found.get("effect") in (None, "none"):
        return None
    added = found.get("added") or [{"axis": found["axis"], "effect": found["effect"]}]
    return ",".join(f"{a['axis']}:{a['effect']}" for a in added)


def _row_metrics(idata, summary, base_scores, blocks_test, test_slice) -> tuple[dict, np.ndarray]:
    from heli_uq.discovery.score import block_scores, compare, gap_metrics

    pp = idata.posterior_predictive
    y_sim = np.asarray(pp["y_sim"]).reshape((-1,) + pp["y_sim"].shape[2:])
    y_pred = np.asarray(pp["y_pred"]).reshape((-1,) + pp["y_pred"].shape[2:])
    y_obs = np.asarray(idata.constant_data["y_obs"])
    # the residual scales of the predictive draws (a thinned subset, indexed by 'draw')
    sig = np.asarray(idata.posterior["sigma"])[:, np.asarray(pp["draw"]), :].reshape(-1, 2)
    full = gap_metrics(y_sim, y_pred, y_obs)
    scores = block_scores(y_sim[:, test_slice], sig, y_obs[test_slice], blocks_test)
    out = {"V_full": full["V"], "windows": summary["windows"], "test_score": float(scores.sum())}
    if base_scores is not None:
        diff, se = compare(scores, base_scores)
        out["test_score_diff"], out["test_score_se"] = float(diff), float(se)
    for key in ("rhat_max", "ess_bulk_min", "divergences", "rhat_max_network_torque",
                "rhat_max_network_weights", "gain_trade_off", "network_band_widths",
                "last_layer"):  # fmt: skip
        if key in summary:
            out[key] = summary[key]
    out["parameters"] = len(idata.posterior.attrs["free_parameters"].split(","))
    return out, scores


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default="experimental")
    ap.add_argument("--train", default="0:91")
    ap.add_argument("--test", default="91:131")
    ap.add_argument("--rows", nargs="+", default=list(ROWS), choices=ROWS)
    ap.add_argument("--effect", default=None, help="AXIS:EFFECT[,...] of the named-effect row")
    ap.add_argument("--hidden", type=int, default=HIDDEN)
    ap.add_argument("--target-accept", type=float, default=None,
                    help="NUTS target acceptance (default: the package's)")
    ap.add_argument("--project", choices=["u", "1,u", "none"], default="u",
                    help="what the FNN(u) output is made orthogonal to (none: the gains and the "
                         "network trade off; the row's gain_trade_off shows by how much)")
    ap.add_argument("--sampler", choices=["nuts", "laplace"], default="nuts",
                    help="nuts (default) or laplace (minutes; its Pareto k says whether to trust it)")
    ap.add_argument("--nn-posterior", choices=["full", "last-layer"], default="full",
                    help="the networks' posterior: every weight (default), or the output weights "
                         "with the hidden layer trained and fixed")
    ap.add_argument("--time-limit", type=float, default=None, metavar="MINUTES",
                    help="stop each row's NUTS at this wall time with the draws made (flagged)")
    add_prior_options(ap)
    add_run_arguments(ap, "hybrid_posterior", chains=4, warmup=500, draws=500)
    args = ap.parse_args(argv)
    if args.time_limit is not None and not args.time_limit > 0:
        ap.error(f"--time-limit: expected minutes > 0, found {args.time_limit:g}")

    import numpyro

    numpyro.set_host_device_count(args.chains)
    from heli_uq.data import load_data
    from heli_uq.discovery.network_equation import equation_model, recover_equation
    from heli_uq.discovery.score import input_blocks
    from heli_uq.errors import ParameterError
    from heli_uq.model.spec import build_model, parse_effects
    from heli_uq.output import sample_posterior
    from heli_uq.output.network import network_pairs
    from heli_uq.output.network_plot import plot_network_torque

    record = load_data(args.data)
    train, test = _parse_window(args.train), _parse_window(args.test)
    t = np.asarray(record.t)
    test_slice = slice(int(np.searchsorted(t, test[0] - 1e-9)), int(np.searchsorted(t, test[1] - 1e-9)))
    blocks_test = input_blocks(np.asarray(record.u)[test_slice], record.dt)
    effect = args.effect or _discovered_effect(RESULTS / "discover_rig" / "discovery.json")
    nn = {"effect": "neural_torque", "axis": "yaw", "hidden": args.hidden}
    # a network of another size than the stored rows' is its own row, run and figure
    other_size = args.hidden != HIDDEN
    sized = f" (h = {args.hidden})" if other_size else ""
    models = {"mechanistic": ("mechanistic", build_model()),
              "effect": (f"+ {effect}", parse_effects(effect)) if effect else None,
              "u": ("+ FNN(u)" + sized + ("" if args.project == "u" else f" (project {args.project})"),
                    build_model([{**nn, "inputs": "u", "project": args.project}])),
              "u,x,v": ("+ FNN(u,x,v)" + sized, build_model([{**nn, "inputs": "u,x,v"}]))}  # fmt: skip
    try:  # a bad --fix / --prior stops before any row is sampled
        for row in args.rows:
            if models.get(row) is not None:
                priors_from_args(args, models[row][1])
    except ParameterError as err:
        ap.error(str(err))
    runs = pathlib.Path(args.runs)
    time_limit = None if args.time_limit is None else 60.0 * args.time_limit  # [s]
    accept = {} if args.target_accept is None else {"target_accept": args.target_accept}
    base_scores, fnn_u = None, None
    # a row run under changed priors is labelled with them and kept in its own run directory
    changed = [*(["priors " + args.priors] if args.priors else []), *(args.prior or []), *(args.fix or [])]
    changed_label = f" ({'; '.join(changed)})" if changed else ""
    changed_dir = "_" + "_".join(re.sub(r"[^A-Za-z0-9.]+", "-", c) for c in changed) if changed else ""
    lines = []
    for row in args.rows:
        t0 = time.perf_counter()
        recovered = None
        if row == "equation":
            if fnn_u is None:
                print("equation: needs the FNN(u) row in the same run; skipped")
                continue
            torque = np.asarray(fnn_u.posterior["nn_torque_yaw"])
            torque = torque.reshape(-1, torque.shape[-1])
            pairs, weights = network_pairs(fnn_u, "yaw")
            points = {"u_theta": pairs[:, 0], "u_psi": pairs[:, 1]}
            recovered = recover_equation(torque, points, weights, project="u")
            source = "every weight" if args.nn_posterior == "full" else "last layer"
            label = f"+ recovered equation (from FNN(u){sized}, {source})"
            model = equation_model(models["u"][1], "yaw", recovered["selected"])
        elif models.get(row) is None:
            print(f"{row}: no discovered effect (run the discover_rig study or pass --effect); skipped")
            continue
        else:
            label, model = models[row]
        # every weight sampled: its own label, run and figure (the stored rows are last-layer ones)
        every = "_every_weight" if args.nn_posterior == "full" and row in ("u", "u,x,v") else ""
        label += (", every weight" if every else "") + changed_label
        print(f"{label}: {args.sampler} ({args.chains} x ({args.warmup} + {args.draws}))", flush=True)
        projected = "" if row != "u" or args.project == "u" else f"_{args.project}"
        size = f"_h{args.hidden}" if other_size and row in ("u", "u,x,v") else ""
        source_run = f"_h{args.hidden}_{args.nn_posterior}" if row == "equation" else ""
        run_dir = runs / (row.replace(",", "") + projected + size + every + source_run + changed_dir)
        idata, summary = sample_posterior(record, run_dir, model=model, train=train,
                                          test=test, error="iid", sampler=args.sampler,
                                          network_posterior=args.nn_posterior, **accept,
                                          priors=priors_from_args(args, model),
                                          time_limit=time_limit,
                                          chains=args.chains, warmup=args.warmup,
                                          draws=args.draws, progress=False)  # fmt: skip
        metrics, scores = _row_metrics(idata, summary, base_scores, blocks_test, test_slice)
        if row == "mechanistic":
            base_scores = scores
        if row == "u":
            fnn_u = idata
            figure = pathlib.Path(args.figures) / f"hybrid_fnn_u_torque{size}{every}.png"
            plot_network_torque(idata, "yaw", figure)
        line = {"row": label, "model": model.label, "train": args.train, "test": args.test,
                **metrics, "seconds": time.perf_counter() - t0,
                "sampler": {"name": args.sampler, "chains": args.chains, "warmup": args.warmup,
                            "draws": args.draws, "pareto_k": summary.get("pareto_k"),
                            "target_accept": summary.get("target_accept"),
                            "health": summary["health"]["flags"]}}  # fmt: skip
        if recovered is not None:
            line["recovered"] = recovered
        line["provenance"] = provenance(__file__, argv, line["seconds"])
        append_jsonl(args.out, line)
        lines.append(line)
        print(json.dumps({k: v for k, v in line.items() if k not in ("windows", "recovered", "provenance")}),
              flush=True)  # fmt: skip
    if lines:
        write_table(pathlib.Path(args.out), args.train, args.test)
    return 0


def write_table(out: pathlib.Path, train: str, test: str) -> None:
    """The table ``out`` with suffix ``.md``: the newest line of each row on this split, over
    every run of ``out`` (a ``.jsonl`` file)."""
    latest = {}
    for text in out.read_text().splitlines():
        line = json.loads(text)
        if (line["train"], line["test"]) == (train, test):
            latest[line["row"]] = line
    _write_table(list(latest.values()), out.with_suffix(".md"))


def _sampler(info: dict) -> str:
    text = info["name"]
    if info.get("pareto_k") is not None:
        text += f" (Pareto k {info['pareto_k']:.2f})"
    return text + (f" {', '.join(info['health'])}" if info.get("health") else "")


def _write_table(lines, path: pathlib.Path) -> None:
    from heli_uq.io import atomic_write_text

    def pct(x):
        return f"{100 * x:.0f} %"

    head = ("| model | V full [rad²] | RMSE θ / ψ train [rad] | RMSE θ / ψ test [rad] "
            "| 90 % cov. θ / ψ train | 90 % cov. θ / ψ test | test score − mechanistic [nats] (se) "
            "| parameters | sampler | R-hat | wall | run |\n"
            "|---|---|---|---|---|---|---|---|---|---|---|---|")  # fmt: skip
    rows = [head]
    for ln in lines:
        tr, te = ln["windows"]["train"], ln["windows"].get("test", {})
        base = ln["row"].split(" (")[0] == "mechanistic"  # also under changed priors
        diff = (f"{ln['test_score_diff']:+.0f} ({ln['test_score_se']:.0f})" if "test_score_diff" in ln
                else "0" if base else "– (no mechanistic row in its run)")  # fmt: skip
        rhat = f"{ln.get('rhat_max', float('nan')):.3f}"
        if "rhat_max_network_torque" in ln:
            rhat += f" (weights {ln['rhat_max_network_weights']:.2f})"
        rows.append(f"| {ln['row']} | {ln['V_full']:.3f} "
                    f"| {tr['rmse']['theta']:.3f} / {tr['rmse']['psi']:.3f} "
                    f"| {te['rmse']['theta']:.3f} / {te['rmse']['psi']:.3f} "
                    f"| {pct(tr['coverage90']['theta'])} / {pct(tr['coverage90']['psi'])} "
                    f"| {pct(te['coverage90']['theta'])} / {pct(te['coverage90']['psi'])} "
                    f"| {diff} | {ln['parameters']} | {_sampler(ln['sampler'])} | {rhat} "
                    f"| {ln['seconds'] / 60:.0f} min | {ln['provenance']['time'][:10]} |")  # fmt: skip
    atomic_write_text(path, "\n".join(rows) + "\n")


if __name__ == "__main__":
    sys.exit(main())
