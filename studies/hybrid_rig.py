"""Hybrid models on the rig record, trained as in the paper: V of the mechanistic model and
of the model with a neural yaw (and pitch) torque.

For the record (``--data``, default the real one) and each window setting, train on
``--train`` (default 0-91 s) and score on ``--test`` (default 91-131 s), plus one run
trained on the whole record (the paper's setting, for its table):

1. the mechanistic model's MAP (iid errors, :func:`heli_uq.inference.prepare_start`);
2. each network (``--networks``; ``u`` = FNN(u), ``uxv`` = FNN(u, x, v), on both axes,
   hidden width ``--hidden``), trained by :func:`heli_uq.inference.train` (Adam 100, then
   L-BFGS 100, on V) with the physics frozen at the MAP, then jointly with it;
3. V [rad^2] (Eq. 1) and the RMSE of pitch and yaw [rad] of each model on the training
   window, the test window and the whole record (simulated from the MAP initial state).

Writes one JSON line per run to ``--out`` (default ``studies/results/hybrid_rig.jsonl``)
and the figure ``studies/figures/hybrid_rig_yaw.png`` (yaw: data, mechanistic, best
hybrid).  Usage::

    python studies/hybrid_rig.py [--data experimental] [--hidden 16] [--networks u uxv]
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import time

import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from _study import FIGURES, RESULTS, append_jsonl, provenance  # noqa: E402

from heli_uq.data import load_data, parse_window  # noqa: E402
from heli_uq.inference import prepare_start, train  # noqa: E402
from heli_uq.model import build_model  # noqa: E402
from heli_uq.probability import loss_v, make_problem  # noqa: E402

#: Network settings by short name: the term options (the paper's FNNs act on both axes;
#: here one network per axis, the same inputs).
NETWORKS = {"u": {"inputs": "u", "project": "u"}, "uxv": {"inputs": "u,x,v", "project": "none"}}
#: The paper's stored results, re-simulated on the rig record (V [rad^2]).
PAPER_V = {"mechanistic": 1.137, "u": 0.114, "uxv": 0.173}


def _scores(problem, params, x0, record, substeps: int) -> dict:
    """V and RMSE on the training window, the test window and the whole record, simulated
    with ``substeps`` (those of the fit: a stiff one blows up a coarser solve)."""
    full = make_problem(record, model=problem.model, error="iid", substeps=substeps)
    ys = np.asarray(full.solve(params, jnp.asarray(x0)).ys)[:, :2]
    out = {}
    windows = {"train": (0, problem.n_train), "full": (0, len(full.y))}
    if problem.test is not None:
        windows["test"] = problem.test
    for name, (a, b) in windows.items():
        r = ys[a:b] - full.y[a:b]
        out[name] = {"V": float(loss_v(ys[a:b], full.y[a:b])),
                     "rmse_theta": float(np.sqrt(np.mean(r[:, 0] ** 2))),
                     "rmse_psi": float(np.sqrt(np.mean(r[:, 1] ** 2)))}  # fmt: skip
    return out, ys


def run(record, train_w, test_w, networks, hidden: int, seed: int) -> tuple[list[dict], dict]:
    """All models of one window setting: rows and the simulations by label."""
    t0 = time.perf_counter()
    base = make_problem(record, train_w, test_w, error="iid")
    start = prepare_start(base, n_starts=4, seed=seed)
    params, x0 = start.map_point()
    scores, ys = _scores(start.problem, params, x0, record, start.problem.substeps)
    rows = [{"model": "mechanistic", "training": "MAP", "scores": scores,
             "seconds": time.perf_counter() - t0}]  # fmt: skip
    sims = {"mechanistic": ys}
    for key in networks:
        items = [{"effect": "neural_torque", "axis": axis, "hidden": hidden, **NETWORKS[key]}
                 for axis in ("pitch", "yaw")]  # fmt: skip
        problem = make_problem(record, train_w, test_w, model=build_model(items), error="iid")
        current = dict(params)
        for mode, trainable in (("physics frozen", None), ("joint", "all")):
            result = train(problem, current, x0, trainable=trainable)
            current = result.params
            scores, ys = _scores(problem, current, x0, record, result.substeps)
            rows.append({"model": f"+ FNN({key})", "training": mode, "hidden": hidden,
                         "scores": scores, "v_start": result.v_start, "substeps": result.substeps,
                         "lbfgs_steps": result.lbfgs_steps, "seconds": result.seconds})  # fmt: skip
            sims[f"+ FNN({key}), {mode}"] = ys
    return rows, sims


def _figure(record, sims, split, path):
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(10, 4))
    ax.plot(record.t, np.degrees(record.y[:, 1]), color="k", lw=1.2, label="rig record")
    for label, ys in sims.items():
        ax.plot(record.t, np.degrees(ys[:, 1]), lw=1, label=label)
    if split is not None:
        ax.axvline(split, color="grey", ls="--", lw=1)
        ax.text(split, ax.get_ylim()[1], " test window", va="top", fontsize=8, color="grey")
    ax.set_xlabel("time t [s]")
    ax.set_ylabel("yaw angle psi [deg]")
    ax.set_title("Yaw on the rig record: mechanistic MAP and hybrid models (trained on the "
                 "training window)")  # fmt: skip
    ax.legend(fontsize=8, loc="best")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default="experimental")
    ap.add_argument("--train", default="0:91")
    ap.add_argument("--test", default="91:131")
    ap.add_argument("--networks", nargs="+", default=list(NETWORKS), choices=list(NETWORKS))
    ap.add_argument("--hidden", type=int, default=16, help="hidden units (paper: 16)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=str(RESULTS / "hybrid_rig.jsonl"))
    args = ap.parse_args(argv)
    t_run = time.perf_counter()
    record = load_data(args.data)
    settings = (("train/test", parse_window(args.train), parse_window(args.test)),
                ("whole record", None, None))  # fmt: skip
    all_rows = []
    for label, train_w, test_w in settings:
        rows, sims = run(record, train_w, test_w, args.networks, args.hidden, args.seed)
        if train_w is not None:
            best = min((k for k in sims if k != "mechanistic"),
                       key=lambda k: float(np.mean((sims[k] - record.y) ** 2)))  # fmt: skip
            _figure(record, {"mechanistic (MAP)": sims["mechanistic"], best: sims[best]},
                    test_w[0] if test_w else None, FIGURES / "hybrid_rig_yaw.png")  # fmt: skip
        for row in rows:
            row["setting"] = label
        all_rows += rows
    line = {"data": str(record.source), "rows": all_rows, "paper_V": PAPER_V,
            **provenance(__file__, argv, time.perf_counter() - t_run)}  # fmt: skip
    append_jsonl(args.out, line)
    print("| setting | model | training | V train | V test | V full | RMSE psi full [rad] |")
    print("|---|---|---|---|---|---|---|")
    for r in all_rows:
        s = r["scores"]
        test = f"{s['test']['V']:.4f}" if "test" in s else "-"
        print(f"| {r['setting']} | {r['model']} | {r['training']} | {s['train']['V']:.4f} | {test} | "
              f"{s['full']['V']:.4f} | {s['full']['rmse_psi']:.4f} |")  # fmt: skip
    print(f"appended to {args.out}")


if __name__ == "__main__":
    main()
