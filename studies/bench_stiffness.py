"""Speed of the stiffness check over a run's draws: all draws in one call against one call per draw.

After every run :func:`heli_uq.simulation.stiffness_check` computes each draw's stiffness rate
(:meth:`heli_uq.model.HeliModel.stiffness`): the smallest yaw inertia over the record's pitch
angles, then each term's rate.  An emcee run at its defaults keeps 144,000 draws (4
ensembles x 1000 kept steps x 36 walkers); computed one draw at a time that check took 46 of
a 1 s record's 72 s run (README, Tests and CI).  This benchmark times, in one run and on the
same draws:

- ``vectorised``: :func:`heli_uq.simulation.stiffness.stiffness_rates`, every draw at once;
- ``per_draw`` (the baseline): one :meth:`HeliModel.stiffness` call per draw with scalar
  values, on the first ``--baseline-draws`` draws, scaled to all of them;

checks that both give the same rates (relative difference ``max_rel_diff``) and appends one
JSON line (``studies/results/bench_stiffness.jsonl``).  Usage::

    python studies/bench_stiffness.py                    # 144,000 draws, 9,100 pitch angles
    python studies/bench_stiffness.py --draws 4000 --baseline-draws 1000
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys
import time

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from _study import RESULTS, append_jsonl, provenance  # noqa: E402

from heli_uq.model import RIG_FIT, build_model  # noqa: E402
from heli_uq.simulation.stiffness import stiffness_rates  # noqa: E402

#: The stiff terms of the vocabulary, on both axes: every term with a rate contributes.
EFFECTS = ("yaw:coulomb_friction", "yaw:stiction", "yaw:torsional_spring", "pitch:coulomb_friction")
#: Parameters drawn (log-normal spread around their values) and their values.
DRAWN = {"r_c": None, "m": None, "J_bc": None, "J_s": None, "h": None,
         "F_c_yaw": 0.012, "F_s_yaw": 0.003, "k_yaw": 0.004, "F_c_pitch": 0.003}  # fmt: skip
#: Relative spread (sd of the log) of the draws.
SPREAD = 0.1


def draws_and_angles(n: int, n_angles: int, seed: int):
    """``(values, draws, thetas)``: the model's values, ``n`` draws of :data:`DRAWN`
    ``{name: (n,)}`` and ``n_angles`` pitch angles [rad] in the rig record's range."""
    rng = np.random.default_rng(seed)
    values = {**RIG_FIT, **{k: v for k, v in DRAWN.items() if v is not None}, "psi_0_yaw": 0.0}
    draws = {k: values[k] * np.exp(SPREAD * rng.standard_normal(n)) for k in DRAWN}
    thetas = rng.uniform(-0.68, -0.08, size=n_angles)
    return values, draws, thetas


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--draws", type=int, default=144_000)
    parser.add_argument("--angles", type=int, default=9_100, help="pitch angles (a 91 s window at 0.01 s)")
    parser.add_argument("--baseline-draws", type=int, default=2_000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default=str(RESULTS / "bench_stiffness.jsonl"))
    args = parser.parse_args(argv)
    t_start = time.perf_counter()
    model = build_model(list(EFFECTS))
    values, draws, thetas = draws_and_angles(args.draws, args.angles, args.seed)
    stiffness_rates(model, {k: v[:10] for k, v in draws.items()}, fixed=values, thetas=thetas)  # warm
    t0 = time.perf_counter()
    rates = stiffness_rates(model, draws, fixed=values, thetas=thetas)
    vectorised = time.perf_counter() - t0
    m = min(args.baseline_draws, args.draws)
    t0 = time.perf_counter()
    base = np.array([model.stiffness({**values, **{k: float(v[i]) for k, v in draws.items()}}, thetas)
                     for i in range(m)])  # fmt: skip
    per_draw = (time.perf_counter() - t0) * args.draws / m
    line = {"draws": args.draws, "angles": args.angles, "baseline_draws": m, "effects": list(EFFECTS),
            "vectorised_s": vectorised, "per_draw_s_scaled": per_draw, "speedup": per_draw / vectorised,
            "max_rel_diff": float(np.max(np.abs(rates[:m] - base) / base)),
            **provenance(__file__, sys.argv if argv is None else argv,
                         time.perf_counter() - t_start)}  # fmt: skip
    append_jsonl(pathlib.Path(args.out), line)
    print(json.dumps({k: line[k] for k in ("draws", "vectorised_s", "per_draw_s_scaled", "speedup",
                                           "max_rel_diff")}))  # fmt: skip
    return line


if __name__ == "__main__":
    main()
