"""How the SBC wall time scales with the number of Dask workers (issue 12, scale-out).

Runs ``studies/sbc.py`` once per worker count, each time in a fresh process, into a fresh
output directory and with a fresh JAX compilation cache (so no run profits from another's
compiled programs), and appends one JSON line per run to ``results/sbc_scaling.jsonl``:
wall time [s], replicates, mean time per replicate inside its worker [s], throughput
[s per replicate] and the speed-up over the first worker count.  Load on the machine from
other jobs distorts the numbers: the 1-minute load average at the end is recorded.

``--records embedded arguments`` also runs each worker count with the records embedded in
the compiled programs as constants (JAX's old default: every replicate compiles its own
programs) and as arguments (the package's setting, :mod:`heli_uq._jax_config`: replicates
of one record length share them through the persistent cache), and prints the ratio.

Usage: ``python studies/sbc_scaling.py [--workers 1 2] [--replicates 8] [--records ...]``.
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from _study import RESULTS, append_jsonl, provenance  # noqa: E402

from heli_uq._jax_config import RECORDS_AS_ARGUMENTS  # noqa: E402

HERE = pathlib.Path(__file__).resolve().parent
#: The replicate of the stored SBC run (studies/results/sbc_v2), shortened by --draws.
SBC_ARGS = ("--h-sd", "0", "--chains", "1", "--warmup", "200", "--x0-prior", "generator", "--duration", "5")
#: How a run's records reach the compiled programs: the JAX settings of each.
RECORDS = {
    "arguments": RECORDS_AS_ARGUMENTS,
    "embedded": {"JAX_USE_SIMPLIFIED_JAXPR_CONSTANTS": "false", "JAX_EMBEDDED_CONSTANTS_MAX_BYTES": "32"},
}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--replicates", type=int, default=8)
    ap.add_argument("--draws", type=int, default=100)
    ap.add_argument("--duration", type=float, default=5.0)
    ap.add_argument("--records", nargs="+", choices=list(RECORDS), default=["arguments"],
                    help="how records reach the compiled programs (module docstring)")
    ap.add_argument("--out", default=str(RESULTS / "sbc_scaling.jsonl"))
    args = ap.parse_args(argv)
    first = None
    with tempfile.TemporaryDirectory(prefix="sbc_scaling_") as tmp:
        for w, records in ((w, r) for w in args.workers for r in args.records):
            out, cache = pathlib.Path(tmp) / f"out_{w}_{records}", pathlib.Path(tmp) / f"cache_{w}_{records}"
            cmd = [sys.executable, str(HERE / "sbc.py"), "--replicates", str(args.replicates),
                   *SBC_ARGS[:-1], str(args.duration), "--draws", str(args.draws), "--out", str(out),
                   "--workers", str(w)]  # fmt: skip
            env = {**os.environ, **RECORDS[records], "JAX_COMPILATION_CACHE_DIR": str(cache)}
            t0 = time.perf_counter()
            code = subprocess.run(cmd, env=env, check=False).returncode
            wall = time.perf_counter() - t0
            reps = [json.loads(p.read_text()) for p in sorted(out.glob("rep_*.json"))]
            first = first or wall
            line = {"scheduler": "local", "workers": w, "records": records, "replicates": len(reps),
                    "exit_code": code,
                    "wall_s": wall, "speedup_over_first": first / wall,
                    "per_replicate_wall_s_mean": (sum(r["provenance"]["wall_s"] for r in reps)
                                                  / max(len(reps), 1)),
                    "throughput_s_per_replicate": wall / max(len(reps), 1),
                    "ess_min_median": (sorted(min(r["ess"].values()) for r in reps)[len(reps) // 2]
                                       if reps else None),
                    "loadavg_1min_at_end": os.getloadavg()[0],
                    "note": "fresh out dir and fresh JAX compilation cache per run",
                    "provenance": provenance(__file__, argv, wall)}  # fmt: skip
            append_jsonl(args.out, line)
            print(f"{w} worker(s), records as {records}: {wall:.0f} s for {len(reps)} replicates "
                  f"({line['throughput_s_per_replicate']:.0f} s each, "
                  f"speed-up {line['speedup_over_first']:.2f})")
            if code != 0:
                return code
    return 0


if __name__ == "__main__":
    sys.exit(main())
