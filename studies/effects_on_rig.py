"""Every named effect on each axis, fitted alone on the rig record: MAP V, RMSE, parameters.

For the paper's model and for each effect of the vocabulary on each axis (``--axes``), on
the record (``--data``, default the real one; ``--window`` to shorten), with iid errors:

* the multi-start MAP of the posterior (:func:`heli_uq.inference.prepare_start`), with the
  solver substeps the fitted parameters need;
* the paper's loss V [rad^2] and the RMSE of pitch and yaw [rad] of the MAP simulation;
* each effect parameter's MAP value and 95 % interval of the Laplace approximation
  (draws of the Gaussian in the sampler's unconstrained coordinates, mapped to physical
  units, so log-scaled parameters get skewed intervals), with its ratio to the yaw or
  pitch inertia, which the angles identify (the parameter itself carries the unidentified
  common inertia scale);
* the wall time of the fit.

Writes one JSON line per model to ``--out`` (default
``studies/results/effects_on_rig.jsonl``), then prints a markdown table of all lines of
this run.  Usage::

    python studies/effects_on_rig.py [--data experimental] [--window 0:131] [--axes yaw pitch]
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys
import time

import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from _study import RESULTS, append_jsonl, provenance  # noqa: E402

from heli_uq.data import load_data, parse_window  # noqa: E402
from heli_uq.inference import prepare_start  # noqa: E402
from heli_uq.inference.density import constrain_draws  # noqa: E402
from heli_uq.model import EFFECTS, build_model  # noqa: E402
from heli_uq.model.terms.rigid_body import pitch_inertia, yaw_inertia  # noqa: E402
from heli_uq.probability import loss_v, make_problem  # noqa: E402

#: Draws of the Laplace approximation for the intervals.
LAPLACE_DRAWS = 4000
INTERVAL = (0.025, 0.975)


def fit(record, effects, seed: int, n_starts: int) -> dict:
    """MAP, V, RMSE and Laplace intervals of the model with ``effects`` (list of "axis:effect")."""
    model = build_model(effects)
    t0 = time.perf_counter()
    problem = make_problem(record, model=model, error="iid")
    start = prepare_start(problem, n_starts=n_starts, seed=seed)
    problem = start.problem
    density = start.density
    best = {k: v[0] for k, v in constrain_draws(density, start.x_map[None]).items()}
    params = {n: float(best[n]) if n in best else float(p.a) for n, p in problem.priors.params.items()}
    x0 = jnp.asarray([best[n] for n in ("theta0", "psi0", "omega_theta0", "omega_psi0")])
    ys = np.asarray(problem.solve(params, x0).ys)
    resid = ys[:, :2] - problem.y
    sites = start.laplace_draws(LAPLACE_DRAWS, seed=seed)
    theta_ref = problem.coords.yaw_theta_ref
    out = {}
    for term in model.effects:
        for par in term.parameters():
            inertia = yaw_inertia if par.axis == "yaw" else (lambda p, _t: pitch_inertia(p))
            entry = {"map": params[par.name], "unit": par.unit,
                     "ci95": np.quantile(sites[par.name], INTERVAL).tolist()}  # fmt: skip
            if par.scales_with_inertia:
                ratio = sites[par.name] / inertia(sites, theta_ref)
                entry["ratio_to_inertia"] = {
                    "map": params[par.name] / float(inertia(params, theta_ref)),
                    "ci95": np.quantile(ratio, INTERVAL).tolist(),
                    "inertia": "M22(theta_ref)" if par.axis == "yaw" else "M11",
                }  # fmt: skip
            out[par.name] = entry
    return {
        "model": model.label, "effects": list(effects), "substeps": problem.substeps,
        "map_value": start.map_value, "map_decrement": start.map_decrement,
        "loss_v": float(loss_v(ys, problem.y)),
        "rmse": {"theta": float(np.sqrt(np.mean(resid[:, 0] ** 2))),
                 "psi": float(np.sqrt(np.mean(resid[:, 1] ** 2)))},
        "sigma_map": [float(best["sigma"][0]), float(best["sigma"][1])],
        "parameters": out, "fit_seconds": time.perf_counter() - t0,
    }  # fmt: skip


def table(rows) -> str:
    """Markdown table of the fits (one line per model)."""
    lines = ["| model | V [rad^2] | RMSE theta / psi [rad] | -log p at MAP | effect parameters "
             "(MAP, 95 % Laplace interval) | substeps | fit [s] |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        pars = "; ".join(
            f"{n} = {v['map']:.3g} [{v['ci95'][0]:.3g}, {v['ci95'][1]:.3g}] {v['unit']}"
            for n, v in r["parameters"].items()) or "-"  # fmt: skip
        lines.append(f"| {r['model']} | {r['loss_v']:.4f} | {r['rmse']['theta']:.4f} / "
                     f"{r['rmse']['psi']:.4f} | {r['map_value']:.1f} | {pars} | {r['substeps']} | "
                     f"{r['fit_seconds']:.0f} |")  # fmt: skip
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default="experimental")
    ap.add_argument("--window", default=None, metavar="A:B")
    ap.add_argument("--axes", nargs="+", default=["yaw", "pitch"], choices=["yaw", "pitch"])
    ap.add_argument("--effects", nargs="+", default=sorted(EFFECTS), choices=sorted(EFFECTS))
    ap.add_argument("--starts", type=int, default=4, help="MAP starts per model (default 4)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=str(RESULTS / "effects_on_rig.jsonl"))
    args = ap.parse_args(argv)
    record = load_data(args.data)
    if args.window:
        record = record.window(*parse_window(args.window))
    specs = [[]] + [[f"{axis}:{kind}"] for axis in args.axes for kind in args.effects]
    rows = []
    for effects in specs:
        row = fit(record, effects, args.seed, args.starts)
        row.update(provenance(__file__, argv, row["fit_seconds"]), record=str(record.source),
                   window=args.window)  # fmt: skip
        append_jsonl(args.out, row)
        rows.append(row)
        print(json.dumps({k: row[k] for k in ("model", "loss_v", "rmse", "fit_seconds")}), flush=True)
    print(table(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
