"""What a neural term costs: the log-density gradient of hybrid models against the
mechanistic one, on the same record, in one run.

For each model (the paper's; + FNN(u) on yaw with 4 and 16 hidden units; + FNN(u,x,v)
with 16) it builds the package's log density on the training window (iid errors, the
model's start values), compiles its value and gradient, then times them interleaved
(``--repeats`` rounds, the order rotated each round) and appends one JSON line to
``results/bench_hybrid.jsonl`` with the medians [ms], the number of sampled coordinates
and each model's gradient time relative to the mechanistic one.

Usage: ``python studies/bench_hybrid.py [--window 0:91] [--repeats 30]``.
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import time

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from _study import RESULTS, append_jsonl, provenance  # noqa: E402

MODELS = {"mechanistic": [],
          "FNN(u) h=4": [{"effect": "neural_torque", "axis": "yaw", "inputs": "u", "hidden": 4}],
          "FNN(u) h=16": [{"effect": "neural_torque", "axis": "yaw", "inputs": "u", "hidden": 16}],
          "FNN(u,x,v) h=16": [{"effect": "neural_torque", "axis": "yaw", "inputs": "u,x,v",
                               "hidden": 16}]}  # fmt: skip


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default="experimental")
    ap.add_argument("--window", default="0:91")
    ap.add_argument("--repeats", type=int, default=30)
    ap.add_argument("--out", default=str(RESULTS / "bench_hybrid.jsonl"))
    args = ap.parse_args(argv)
    from heli_uq.data import load_data, parse_window
    from heli_uq.inference.density import log_density_setup
    from heli_uq.model.spec import build_model
    from heli_uq.probability import make_problem

    t0 = time.perf_counter()
    record = load_data(args.data).window(*parse_window(args.window))
    fns, dims = {}, {}
    for name, effects in MODELS.items():
        density = log_density_setup(make_problem(record, model=build_model(effects), error="iid"))
        x = np.zeros(density.dim)
        for f in (density.potential_jit, density.grad_jit):
            np.asarray(f(x))  # compile
        fns[name] = (density, x)
        dims[name] = int(density.dim)
    times = {n: {"value": [], "grad": []} for n in MODELS}
    names = list(MODELS)
    for r in range(args.repeats):
        for name in names[r % len(names):] + names[: r % len(names)]:
            density, x = fns[name]
            for kind, f in (("value", density.potential_jit), ("grad", density.grad_jit)):
                t = time.perf_counter()
                np.asarray(f(x))
                times[name][kind].append(1e3 * (time.perf_counter() - t))
    med = {n: {k: float(np.median(v)) for k, v in d.items()} for n, d in times.items()}
    base = med["mechanistic"]["grad"]
    line = {"data": args.data, "window": args.window, "samples": int(record.n), "dims": dims,
            "median_ms": med, "grad_vs_mechanistic": {n: m["grad"] / base for n, m in med.items()},
            "grad_vs_value": {n: m["grad"] / m["value"] for n, m in med.items()},
            "repeats": args.repeats}  # fmt: skip
    line["provenance"] = provenance(__file__, argv, time.perf_counter() - t0)
    append_jsonl(args.out, line)
    for n in MODELS:
        print(f"{n:18s} d={dims[n]:4d}  value {med[n]['value']:7.2f} ms  gradient {med[n]['grad']:7.2f} ms  "
              f"({line['grad_vs_mechanistic'][n]:.2f}x the mechanistic gradient)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
