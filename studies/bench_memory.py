"""Peak resident memory (max RSS) and wall time of default ``heli-uq sample`` runs.

Goal: every default run of ``heli-uq sample`` (NUTS or emcee, iid errors, default chains,
warm-up and draws), on a 30 s window and on the full 131 s record, peaks at **<= 4 GB**
resident memory (:data:`LIMIT_MB`).

Each run is ``python -m heli_uq.cli sample --sampler S --error iid [--window A:B] --out
DIR`` in a fresh subprocess, started by its own small wrapper process (``python -c``,
:data:`WRAPPER`) that waits for it and reports
``resource.getrusage(RUSAGE_CHILDREN).ru_maxrss`` (kB on Linux; reported in MB = 2^20
bytes): the peak RSS of that one run alone, whatever ran before it, plus its wall time
[s] and CPU time.  One JSON line per run goes to ``--out`` (default
``studies/results/bench_memory.jsonl``).  Usage::

    python studies/bench_memory.py                       # nuts + emcee on 0:30 and full
    python studies/bench_memory.py --sampler nuts --window 0:30
    python studies/bench_memory.py --window 0:3 --warmup 20 --draws 20   # smoke run
    python studies/bench_memory.py --sampler nuts --window full --effects yaw:quadratic_drag

``--chains``, ``--warmup``, ``--draws``, ``--effects`` and ``--target-accept`` are passed
through to ``heli-uq sample`` (default: its defaults, 4 x (1000 + 1000)); the child's
output goes to ``WORK/<sampler>_<window>.log``.  A default NUTS run on the full record
takes ~11 min on two cores; run the default study alone on the machine.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import subprocess
import sys
import tempfile

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from _study import RESULTS, append_jsonl, provenance  # noqa: E402

#: The goal: peak resident memory of one default run [MB].
LIMIT_MB = 4096
#: Windows measured by default (``full``: the whole record).
WINDOWS = ("0:30", "full")
SAMPLERS = ("nuts", "emcee")
#: Options passed through to ``heli-uq sample`` when given.
PASSED = ("chains", "warmup", "draws", "effects", "target_accept")
#: kB per MB (``ru_maxrss`` is in kB on Linux).
KB_PER_MB = 1024
#: The wrapper: ``python -c WRAPPER RESULT.json CMD...`` runs CMD, waits for it and writes
#: its return code, wall time [s], peak RSS [kB] and CPU times [s] to RESULT.json.
WRAPPER = """\
import json, resource, subprocess, sys, time
t0 = time.perf_counter()
code = subprocess.call(sys.argv[2:])
wall = time.perf_counter() - t0
ru = resource.getrusage(resource.RUSAGE_CHILDREN)
with open(sys.argv[1], "w") as fh:
    json.dump({"returncode": code, "wall_s": wall, "maxrss_kb": ru.ru_maxrss,
               "user_s": ru.ru_utime, "sys_s": ru.ru_stime}, fh)
"""


def sample_command(sampler: str, window: str, out: pathlib.Path, args) -> list[str]:
    """The ``heli-uq sample`` command line of one run."""
    cmd = [sys.executable, "-m", "heli_uq.cli", "sample", "--data", args.data,
           "--sampler", sampler, "--error", args.error, "--no-progress", "--out", str(out)]  # fmt: skip
    if window != "full":
        cmd += ["--window", window]
    for name in PASSED:
        value = getattr(args, name)
        if value is not None:
            cmd += [f"--{name.replace('_', '-')}", str(value)]
    return cmd


def measure(cmd: list[str], log: pathlib.Path) -> dict:
    """Run ``cmd`` under a fresh wrapper process; its peak RSS, wall and CPU times."""
    with tempfile.TemporaryDirectory() as tmp:
        result = pathlib.Path(tmp) / "rusage.json"
        with open(log, "w", encoding="utf-8") as fh:
            subprocess.run([sys.executable, "-c", WRAPPER, str(result), *cmd], stdout=fh,
                           stderr=subprocess.STDOUT, check=False)  # fmt: skip
        return json.loads(result.read_text())


def _summary_facts(out: pathlib.Path) -> dict:
    """A few facts of the run's ``summary.json`` (if it was written)."""
    path = out / "summary.json"
    if not path.is_file():
        return {}
    s = json.loads(path.read_text())
    keys = ("sampler", "chains", "draws", "substeps", "map_seconds", "warmup_seconds", "wall_s",
            "rhat_max", "ess_bulk_min", "ess_tail_min", "divergences", "mean_leapfrog_steps",
            "step_size", "target_accept", "map_decrement", "health")  # fmt: skip
    return {k: s[k] for k in keys if k in s}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default="experimental", help="record: 'experimental' or CSV path")
    ap.add_argument("--window", action="append", metavar="A:B|full",
                    help=f"window [s] of the record, or 'full' (repeatable; default "
                         f"{' and '.join(WINDOWS)})")
    ap.add_argument("--sampler", action="append", choices=SAMPLERS,
                    help="sampler (repeatable; default both)")
    ap.add_argument("--error", choices=("iid", "ar1"), default="iid")
    ap.add_argument("--chains", type=int, default=None, help="passed to heli-uq sample")
    ap.add_argument("--warmup", type=int, default=None, help="passed to heli-uq sample")
    ap.add_argument("--draws", type=int, default=None, help="passed to heli-uq sample")
    ap.add_argument("--effects", default=None, metavar="AXIS:EFFECT,...",
                    help="passed to heli-uq sample (default: the paper's model)")
    ap.add_argument("--target-accept", type=float, default=None,
                    help="passed to heli-uq sample (NUTS)")
    ap.add_argument("--work", default=None,
                    help="directory of the runs' outputs and logs (default: a temporary one)")
    ap.add_argument("--out", default=str(RESULTS / "bench_memory.jsonl"))
    args = ap.parse_args(argv)
    windows = args.window or list(WINDOWS)
    samplers = args.sampler or list(SAMPLERS)

    with tempfile.TemporaryDirectory(prefix="heli_uq_bench_memory_") as tmp:
        work = pathlib.Path(args.work or tmp)
        work.mkdir(parents=True, exist_ok=True)
        failed = 0
        for window in windows:
            for sampler in samplers:
                tag = f"{sampler}_{window.replace(':', '-')}"
                out = work / tag
                cmd = sample_command(sampler, window, out, args)
                usage = measure(cmd, work / f"{tag}.log")
                mb = usage["maxrss_kb"] / KB_PER_MB
                row = {"bench": "memory", "sampler": sampler, "window": window,
                       "data": args.data, "error": args.error,
                       **{k: getattr(args, k) for k in PASSED},
                       "max_rss_mb": mb, "limit_mb": LIMIT_MB, "within_limit": mb <= LIMIT_MB,
                       "returncode": usage["returncode"], "cpu_user_s": usage["user_s"],
                       "cpu_sys_s": usage["sys_s"], "command": cmd[2:],
                       "summary": _summary_facts(out)}  # fmt: skip
                row.update(provenance(__file__, argv, usage["wall_s"]))
                append_jsonl(args.out, row)
                status = "ok" if usage["returncode"] == 0 else f"FAILED (exit {usage['returncode']})"
                print(f"{sampler:5s} window {window:>6s}: peak RSS {mb:8.1f} MB "
                      f"({'<=' if mb <= LIMIT_MB else '>'} {LIMIT_MB} MB), wall "
                      f"{usage['wall_s']:7.1f} s, {status}", flush=True)  # fmt: skip
                if usage["returncode"] != 0:
                    failed += 1
                    print(f"  log: {work / f'{tag}.log'}" + ("" if args.work else " (deleted)"))
                    print("  " + "\n  ".join((work / f"{tag}.log").read_text().splitlines()[-5:]))
    print(f"appended to {args.out}")
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
