"""Does the rig ask for stiction?  Yaw friction + offset with and without a breakaway excess.

On the rig record's split (fit 0-91 s, predict 91-131 s) two models are fitted by the
discovery candidates' MAP and Laplace predictive
(:func:`heli_uq.discovery.candidates.fit_and_score`):

* ``yaw:coulomb_friction,yaw:torque_offset``: one start from the model's start values
  (it reaches the low-``J_s`` basin from there; README, Discovery);
* the same ``+ yaw:stiction`` (the Stribeck law, :mod:`heli_uq.model.terms.stiction`),
  started from the first model's MAP with ``F_s_yaw`` = :data:`F_S_START`: the model nests
  the first one, and a cold start lands in a basin 5600 nats worse (``J_s`` 0.012 kg m^2).

Writes one JSON line per model to ``results/stiction_rig.jsonl`` (MAP, ``-log p``, gap
metrics on both windows, held-out block score, the importance check of the Laplace draws)
and ``figures/stiction_rig.png`` (yaw of both MAP simulations against the record).
Usage: ``python studies/stiction_rig.py`` (about 12 min on 2 cores).
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

#: Breakaway excess [N m] the stiction model starts from (a fifth of the sliding level the
#: friction + offset fit finds, 0.013 N m).
F_S_START = 0.0025
PAIR = ("yaw:coulomb_friction", "yaw:torque_offset")
STRIBECK = ("yaw:coulomb_friction", "yaw:stiction", "yaw:torque_offset")


def _label(effects) -> str:
    return "+ stiction" if "yaw:stiction" in effects else "friction + offset"


def _plot(record, fits, train, test, path) -> None:
    import matplotlib.pyplot as plt

    from heli_uq.figure import save_figure
    from heli_uq.model import X0_NAMES, build_model
    from heli_uq.simulation import simulate

    t = np.asarray(record.t)
    fig, ax = plt.subplots(figsize=(11, 4.2))
    ax.axvspan(*test, color="0.88", label="test window (not fitted)")
    ax.plot(t, np.degrees(record.y[:, 1]), "k", lw=0.8, label="measured")
    for (label, fit), color in zip(fits, ("tab:orange", "tab:green")):
        model = build_model(list(fit["effects"]))
        p = {k: v for k, v in fit["map"].items() if k not in X0_NAMES}
        x0 = [fit["map"][k] for k in X0_NAMES]
        ys = np.asarray(simulate(p, x0, record.u, record.dt, model=model, substeps=fit["substeps"]))
        ax.plot(t, np.degrees(ys[:, 1]), color=color, lw=1.2,
                label=f"{label}: test yaw RMSE {fit['score']['rmse_psi']:.3f} rad")  # fmt: skip
    ax.set_xlabel("time t [s]")
    ax.set_ylabel("yaw ψ [deg]")
    ax.set_title(f"Rig record, MAP simulations fitted on {train[0]:g}–{train[1]:g} s: "
                 "yaw friction + offset, with and without stiction")
    ax.legend(loc="upper left", fontsize=8)
    ax.grid(alpha=0.3)
    save_figure(fig, path)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(RESULTS / "stiction_rig.jsonl"))
    ap.add_argument("--figure", default=str(FIGURES / "stiction_rig.png"))
    ap.add_argument("--train", default="0:91", metavar="A:B", help="fitting window [s] (default 0:91)")
    ap.add_argument("--test", default="91:131", metavar="C:D", help="held-out window [s] (default 91:131)")
    ap.add_argument("--replot", action="store_true",
                    help="only draw the figure from the last two lines of --out (no fits)")
    args = ap.parse_args(argv)

    from heli_uq.data import load_data, parse_window
    from heli_uq.discovery.candidates import FitTask, fit_and_score

    record = load_data("experimental")
    train, test = parse_window(args.train), parse_window(args.test)
    record = record.window(train[0], test[1])
    if args.replot:
        lines = [json.loads(t) for t in pathlib.Path(args.out).read_text().splitlines()[-2:]]
        _plot(record, [(_label(ln["effects"]), ln) for ln in lines], train, test, pathlib.Path(args.figure))
        return 0
    fits = []
    for effects, guesses in ((PAIR, ()), (STRIBECK, None)):
        if guesses is None:  # nested: from the pair's MAP with a small breakaway excess
            guesses = (dict(fits[0][1]["map"], F_s_yaw=F_S_START),)
        t0 = time.perf_counter()
        fit = fit_and_score(FitTask(record, train, test, effects, guesses=guesses, n_starts=1, draws=64))
        fit["block_score"] = float(np.sum(fit.pop("block_scores")))
        line = {"effects": list(effects), **fit, "seconds": time.perf_counter() - t0}
        line["provenance"] = provenance(__file__, argv, line["seconds"])
        append_jsonl(args.out, line)
        fits.append((_label(effects), fit))
        print(f"{', '.join(effects)}: -log p {fit['map_value']:.0f}, train yaw RMSE "
              f"{fit['fit']['rmse_psi']:.3f}, test yaw RMSE {fit['score']['rmse_psi']:.3f} rad, "
              f"coverage {fit['score']['coverage90_psi']:.0%} ({line['seconds']:.0f} s)",
              flush=True)  # fmt: skip
    _plot(record, fits, train, test, pathlib.Path(args.figure))
    return 0


if __name__ == "__main__":
    sys.exit(main())
