"""The compilation cache's minimum compile time: a second record's run, JAX's 1 s against 0.

JAX writes a compiled program to its persistent cache only if it took at least
``JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS`` to compile (JAX's default 1 s).  Most of
this package's programs compile faster than that, so a second record of the same length
(another window of a study, an SBC replicate, a ``discover`` run on the next record)
compiles them again.  :func:`heli_uq.executor.use_compilation_cache` sets the minimum to
:data:`~heli_uq.executor.MIN_COMPILE_SECONDS` (0 s) unless the user set one.

For each minimum (1 s, then 0 s) and each command (``sample``, ``discover``), with an empty
cache directory of its own: the command runs on a synthetic record (seed 1; the cold run)
and then on a second record of the same length and model (seed 2; the warm run).  Each run
is a fresh ``python -m heli_uq.cli`` process.  ``sbc`` is one serial run of
``studies/sbc.py`` (:data:`SBC_ARGS`, 3 replicates): the cold time is replicate 0's, the
warm time the mean of the others' (each replicate clears JAX's in-memory caches).
Printed: the warm runs' wall times and their ratio, 1 s over 0 s (above 1: the package's
setting is faster); one JSON line per command to ``--out`` (default
``studies/results/bench_cache.jsonl``).  Usage::

    python studies/bench_cache.py                      # sample, discover and sbc, ~7 min
    python studies/bench_cache.py --commands sample    # ~2 min

Run it alone on the machine: the runs are timed.
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
from discovery_confusion import make_record  # noqa: E402

import heli_uq  # noqa: E402,F401  (first: its JAX settings)
from heli_uq.executor import CACHE_ENV, MIN_COMPILE_ENV  # noqa: E402
from heli_uq.simulation import synthetic_experiment  # noqa: E402

#: Minimum compile times compared [s]: JAX's default, then the package's.
MINIMA = (1.0, 0.0)
#: Record length [s] and noise [rad] of ``sample``'s records (1 s, as in the CLI tests).
SAMPLE_SECONDS, SAMPLE_NOISE = 1.0, (0.003, 0.003)
#: ``discover``'s records: the confusion study's null records (``make_record``), 30 s of the
#: rig-like staircase, split 21 s / 9 s (as tests/test_discover.py).
DISCOVER_SECONDS, DISCOVER_SPLIT = 30.0, 21.0
#: The SBC run: 3 replicates of 2 s records, one chain of 100 + 50, serial.
SBC_ARGS = ("--replicates", "3", "--duration", "2", "--chains", "1", "--warmup", "100", "--draws", "50",
            "--h-sd", "0", "--x0-prior", "generator", "--scheduler", "serial")  # fmt: skip
COMMANDS = ("sample", "discover", "sbc")


def _records(command: str, work: pathlib.Path) -> list[str]:
    """Two CSV records of one length and model (seeds 1 and 2)."""
    paths = []
    for seed in (1, 2):
        if command == "sample":
            rec = synthetic_experiment(duration=SAMPLE_SECONDS, seed=seed, noise_std=SAMPLE_NOISE)
        else:  # the confusion study's null record: rig-like staircase, noise and quantisation
            rec, _, _ = make_record("none", "rig_steps", seed, DISCOVER_SECONDS)
        paths.append(str(rec.to_csv(work / f"{command}_{seed}.csv")))
    return paths


def _argv(command: str, csv: str, out: pathlib.Path) -> list[str]:
    if command == "sample":
        return ["sample", "--data", csv, "--chains", "2", "--warmup", "50", "--draws", "50", "--error", "iid",
                "--quiet", "--out", str(out)]  # fmt: skip
    return ["discover", csv, "--train", f"0:{DISCOVER_SPLIT:g}",
            "--test", f"{DISCOVER_SPLIT:g}:{DISCOVER_SECONDS:g}",
            "--candidates", "yaw:torque_offset,pitch:torque_offset", "--budget", "quick", "--quiet",
            "--out", str(out)]  # fmt: skip


def _timed(argv: list[str], env: dict) -> float:
    """Wall time [s] of ``python ARGV`` (``-m heli_uq.cli ...`` or a study script)."""
    t0 = time.perf_counter()
    done = subprocess.run([sys.executable, *argv], env=env, capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"bench_cache: {' '.join(argv[:3])} exited {done.returncode}: "
                         f"{done.stderr.strip().splitlines()[-1:]}")  # fmt: skip
    return time.perf_counter() - t0


def _cold_and_warm(command: str, records: list[str], env: dict, work: pathlib.Path) -> tuple[float, float]:
    """The cold and the warm run's wall times [s] (module docstring)."""
    if command == "sbc":
        _timed([str(pathlib.Path(__file__).parent / "sbc.py"), *SBC_ARGS, "--out", str(work)], env)
        walls = [json.loads(p.read_text())["wall_s"] for p in sorted(work.glob("rep_*.json"))]
        return walls[0], sum(walls[1:]) / len(walls[1:])
    cold, warm = (_timed(["-m", "heli_uq.cli", *_argv(command, csv, work / str(i))], env)
                  for i, csv in enumerate(records))  # fmt: skip
    return cold, warm


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--commands", default=",".join(COMMANDS), help=f"comma-separated: {', '.join(COMMANDS)}")
    ap.add_argument("--out", default=str(RESULTS / "bench_cache.jsonl"))
    args = ap.parse_args(argv)
    commands = [c for c in args.commands.split(",") if c]
    if not commands or set(commands) - set(COMMANDS):
        ap.error(f"--commands: expected some of {', '.join(COMMANDS)}, found {args.commands!r}")
    with tempfile.TemporaryDirectory(prefix="heli_uq_bench_cache_") as tmp:
        work = pathlib.Path(tmp)
        for command in commands:
            t_start = time.perf_counter()
            records = [] if command == "sbc" else _records(command, work)
            row = {"bench": "cache", "command": command}
            for minimum in MINIMA:
                cache = work / f"cache_{command}_{minimum:g}"
                env = {**os.environ, CACHE_ENV: str(cache), MIN_COMPILE_ENV: repr(minimum)}
                cold, warm = _cold_and_warm(command, records, env, work / f"out_{command}_{minimum:g}")
                row[f"min{minimum:g}"] = {"cold_s": cold, "warm_s": warm,
                                          "entries": len(list(cache.iterdir()))}  # fmt: skip
            row["warm_ratio_1s_over_0s"] = row["min1"]["warm_s"] / row["min0"]["warm_s"]
            row.update(provenance(__file__, argv, time.perf_counter() - t_start))
            append_jsonl(args.out, row)
            print(f"{command:8s} warm: {row['min1']['warm_s']:6.1f} s at JAX's 1 s minimum, "
                  f"{row['min0']['warm_s']:6.1f} s at 0 s: ratio {row['warm_ratio_1s_over_0s']:.2f} "
                  f"(cold {row['min1']['cold_s']:.1f} / {row['min0']['cold_s']:.1f} s; cache entries "
                  f"{row['min1']['entries']} / {row['min0']['entries']})")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
