"""Does the rig's yaw torque fall off with pitch as the geometry says?  A profile of the tilt.

The paper's yaw torque is ``K_psi_theta u_theta - K_psi_psi u_psi`` at every pitch angle;
the geometry gives it a factor ``cos theta`` (:mod:`heli_uq.model.terms.thrust_tilt`,
tilt ``a`` = 1).  On the rig record's split (fit 0-91 s, predict 91-131 s) the model yaw
friction + yaw offset + ``thrust_tilt`` is fitted (MAP, ``heli_uq.inference.prepare_start``)
with the tilt fixed at each value of ``--grid`` in turn, each fit warm-started from the one
before (the first from the model's start values, which reach the friction + offset basin
of the README), and once with the tilt free, started from the grid's fit at ``--free-start``.

Writes one JSON line per fit to ``results/thrust_tilt_rig.jsonl`` (tilt, ``-log p``, yaw
and pitch RMSE of the MAP simulation on both windows, the MAP) and
``figures/thrust_tilt_rig.png`` (the profile, and the yaw of three fits against the record).
Usage: ``python studies/thrust_tilt_rig.py`` (17 min on 2 cores shared with a NUTS run).
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys
import time

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from _study import FIGURES, RESULTS, append_jsonl, provenance  # noqa: E402

EFFECTS = ("yaw:coulomb_friction", "yaw:torque_offset", "yaw:thrust_tilt")
GRID = "0,0.25,0.5,0.75,1,1.25,1.5"


def _fit(record, train, test, model, tilt, guess):
    """The MAP start with the tilt fixed at ``tilt`` (``None``: free)."""
    from heli_uq.inference import prepare_start
    from heli_uq.model.prior import Prior
    from heli_uq.probability import make_problem
    from heli_uq.probability.priors import PriorSet

    priors = PriorSet.default(model)
    if tilt is not None:
        priors = priors.updated(model, {"a_yaw": Prior("fixed", tilt)})
    problem = make_problem(record, train, test, model=model, priors=priors, error="iid")
    return prepare_start(problem, n_starts=1, guesses=(guess,) if guess else ())


def _rmse(ys, record, window) -> dict:
    t, y = np.asarray(record.t), np.asarray(record.y)
    held = (t >= window[0]) & (t < window[1])
    err = ys[held, :2] - y[held]
    rmse = np.sqrt(np.mean(err**2, axis=0))
    return {"rmse_theta": float(rmse[0]), "rmse_psi": float(rmse[1])}


def _simulate(record, model, line):
    """The MAP simulation (N, 4) of one result line."""
    from heli_uq.model import X0_NAMES
    from heli_uq.simulation import simulate

    fit = line["map"]
    params = {k: v for k, v in fit.items() if k not in X0_NAMES}
    x0 = [fit[k] for k in X0_NAMES]
    return np.asarray(simulate(params, x0, record.u, record.dt, model=model, substeps=line["substeps"]))


def _plot(record, model, lines, free_start, test, path) -> None:
    """The profile (left) and the yaw of the fits at a = 0, ``free_start`` and free (right)."""
    import matplotlib.pyplot as plt

    from heli_uq.figure import save_figure

    pick = {0.0: "a = 0 (paper)", free_start: f"a = {free_start:g}"}
    sims = [(pick[ln["a"]], _simulate(record, model, ln), ln) for ln in lines
            if ln["tilt_fixed"] and ln["a"] in pick]  # fmt: skip
    free = next(ln for ln in lines if not ln["tilt_fixed"])
    sims.append((f"a free: {free['a']:.2f}", _simulate(record, model, free), free))

    grid = [ln for ln in lines if ln["tilt_fixed"]]
    base = next(ln["map_value"] for ln in grid if ln["a"] == 0.0)
    fig, (left, right) = plt.subplots(1, 2, figsize=(14, 4.6),
                                      gridspec_kw={"width_ratios": [1, 1.7], "wspace": 0.45})
    a = [ln["a"] for ln in grid]
    left.plot(a, [base - ln["map_value"] for ln in grid], "o-", color="tab:blue")
    left.set_xlabel("tilt a (0: the paper's yaw torque, 1: × cos θ)")
    left.set_ylabel("log posterior gain over a = 0 [nats]", color="tab:blue")
    left.axvline(1.0, color="0.6", ls=":", lw=1)
    twin = left.twinx()
    twin.plot(a, [ln["test"]["rmse_psi"] for ln in grid], "s--", color="tab:red")
    twin.set_ylabel("test yaw RMSE, 91–131 s [rad]", color="tab:red")
    left.set_title("Profile: tilt fixed, the rest fitted on 0–91 s")
    left.grid(alpha=0.3)
    t = np.asarray(record.t)
    right.axvspan(*test, color="0.9", label="test window (not fitted)")
    right.plot(t, np.degrees(record.y[:, 1]), "k", lw=0.8, label="measured")
    for (label, ys, line), color in zip(sims, ("tab:orange", "tab:green", "tab:purple")):
        right.plot(t, np.degrees(ys[:, 1]), color=color, lw=1.1,
                   label=f"{label}: test yaw RMSE {line['test']['rmse_psi']:.3f} rad")  # fmt: skip
    lo, hi = np.degrees(np.min(record.y[:, 1])), np.degrees(np.max(record.y[:, 1]))
    right.set_ylim(lo - 0.5 * (hi - lo), hi + 0.5 * (hi - lo))
    right.set_xlabel("time t [s]")
    right.set_ylabel("yaw ψ [deg]")
    right.set_title("MAP simulations (yaw friction + offset + tilt)")
    right.legend(loc="upper left", fontsize=7.5)
    right.grid(alpha=0.3)
    save_figure(fig, path)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(RESULTS / "thrust_tilt_rig.jsonl"))
    ap.add_argument("--figure", default=str(FIGURES / "thrust_tilt_rig.png"))
    ap.add_argument("--train", default="0:91", metavar="A:B", help="fitting window [s] (default 0:91)")
    ap.add_argument("--test", default="91:131", metavar="C:D", help="held-out window [s] (default 91:131)")
    ap.add_argument("--grid", default=GRID, help=f"tilt values, in fit order (default {GRID})")
    ap.add_argument("--free-start", type=float, default=1.0,
                    help="grid value whose fit starts the free-tilt fit (default 1)")
    ap.add_argument("--replot", action="store_true",
                    help="only draw the figure from the last grid + 1 lines of --out (no fits)")
    args = ap.parse_args(argv)

    from heli_uq.data import load_data, parse_window
    from heli_uq.model import build_model

    train, test = parse_window(args.train), parse_window(args.test)
    record = load_data("experimental").window(train[0], test[1])
    model = build_model(list(EFFECTS))
    grid = [float(v) for v in args.grid.split(",")]
    if 0.0 not in grid or args.free_start not in grid:
        ap.error("--grid must hold 0 (the reference) and the --free-start value")
    if args.replot:
        stored = pathlib.Path(args.out).read_text().splitlines()[-(len(grid) + 1):]
        lines = [json.loads(t) for t in stored]
        _plot(record, model, lines, args.free_start, test, pathlib.Path(args.figure))
        return 0
    lines, guess, starts = [], None, {}
    for tilt in [*grid, None]:
        if tilt is None:
            guess = starts[args.free_start]
        t0 = time.perf_counter()
        start = _fit(record, train, test, model, tilt, guess)
        guess = start.map_guess()
        if tilt is not None:
            starts[tilt] = guess
        line = {"effects": list(EFFECTS), "a": float(guess["a_yaw"]), "tilt_fixed": tilt is not None,
                "map_value": float(start.map_value), "map_decrement": float(start.map_decrement),
                "substeps": int(start.problem.substeps), "map": guess}  # fmt: skip
        ys = _simulate(record, model, line)
        line.update(train=_rmse(ys, record, train), test=_rmse(ys, record, test),
                    seconds=time.perf_counter() - t0)
        line["provenance"] = provenance(__file__, argv, line["seconds"])
        append_jsonl(args.out, line)
        lines.append(line)
        how = "fixed" if tilt is not None else "free"
        print(f"tilt {line['a']:.3f} ({how}): -log p {line['map_value']:.1f}, "
              f"yaw RMSE train {line['train']['rmse_psi']:.3f} / test {line['test']['rmse_psi']:.3f} rad "
              f"({line['seconds']:.0f} s)", flush=True)  # fmt: skip
    _plot(record, model, lines, args.free_start, test, pathlib.Path(args.figure))
    return 0


if __name__ == "__main__":
    sys.exit(main())
