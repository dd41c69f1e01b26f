"""Shared bits of the study scripts: the provenance of a result and JSON-lines output.

Every study appends one JSON object per run (or per measured case) to a ``.jsonl`` file
under ``studies/results/``; :func:`provenance` gives the fields every such line carries
(package and JAX versions, the command line, the wall time [s], the date, the CPU count and
the machine's speed on a fixed single-core workload, :func:`machine_reference`).
"""

from __future__ import annotations

import json
import math
import os
import pathlib
import sys
import time

import numpy as np

#: Root of the study outputs: ``studies/`` (the stored results), or ``HELI_UQ_STUDY_ROOT``
#: (``python -m studies run --size quick`` sets it to ``studies/quick/``).
ROOT = pathlib.Path(os.environ.get("HELI_UQ_STUDY_ROOT") or pathlib.Path(__file__).resolve().parent)
#: Directory of the study results (JSON lines, summaries).
RESULTS = ROOT / "results"
#: Directory of the study figures.
FIGURES = ROOT / "figures"
#: Iterations of the fixed workload of :func:`machine_reference`.
REFERENCE_LOOPS = 2_000_000


def machine_reference(repeats: int = 3) -> float:
    """Seconds one core takes for a fixed workload, the fastest of ``repeats`` (about 0.15 s each here).

    The machines these studies ran on differ in speed from day to day: the same test suite
    from a fresh clone took 27-31 min on some days and 12 min on another (README, Tests and
    CI).  A wall time means little without the speed it was measured at, so every result
    line carries this reference (``machine_ref_s``): a loop of Python float arithmetic and
    small numpy calls, single-threaded like XLA's compiler and the Python around it.  Divide
    two runs' wall times by their references to compare them.
    """
    best = math.inf
    a = np.full((4, 4), 0.25)
    for _ in range(repeats):
        t0 = time.perf_counter()
        x = 0.0
        for i in range(REFERENCE_LOOPS):
            x += math.sin(i * 1e-3)
            if i % 100 == 0:
                a = np.tanh(a @ a + x * 1e-9)
        best = min(best, time.perf_counter() - t0)
    return best


def provenance(script: str, argv, wall_s: float) -> dict:
    """Fields every result line carries.

    Parameters
    ----------
    script : str
        The study's file (``__file__``); its name is recorded.
    argv : list of str or None
        The arguments given to ``main`` (None: ``sys.argv[1:]``).
    wall_s : float
        Wall time of the run [s].

    The package version is :func:`heli_uq.provenance.code_version`, the release with a
    digest of the package's source (the installed metadata of an editable install may lag
    behind the release, and the release stays the same across commits).
    """
    import jax

    from heli_uq.provenance import code_version

    argv = sys.argv[1:] if argv is None else list(argv)
    return {"heli_uq": code_version(), "jax": jax.__version__,
            "argv": [pathlib.Path(script).name, *argv], "wall_s": float(wall_s),
            "time": time.strftime("%Y-%m-%dT%H:%M:%S"), "cpu_count": os.cpu_count(),
            "machine_ref_s": machine_reference()}  # fmt: skip


def add_run_arguments(ap, name: str, *, chains: int, warmup: int, draws: int) -> None:
    """The NUTS size (``--chains``, ``--warmup``, ``--draws``) and where a posterior study
    keeps its runs (``--runs``, default ``runs/<name>``), result lines (``--out``,
    default ``results/<name>.jsonl``) and figures (``--figures``, default ``figures``)."""
    ap.add_argument("--chains", type=int, default=chains)
    ap.add_argument("--warmup", type=int, default=warmup)
    ap.add_argument("--draws", type=int, default=draws)
    ap.add_argument("--runs", default=str(ROOT / "runs" / name))
    ap.add_argument("--out", default=str(RESULTS / f"{name}.jsonl"))
    ap.add_argument("--figures", default=str(FIGURES))


def append_jsonl(path, row: dict) -> pathlib.Path:
    """Append ``row`` as one JSON line to ``path`` (created with its directory if missing);
    numpy values are written as plain numbers and lists."""
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a", encoding="utf-8") as fh:
        fh.write(json.dumps(row, default=lambda o: np.asarray(o).tolist()) + "\n")
    return path


def record_line(script: str, argv, path, line: dict) -> None:
    """Append ``line`` with its :func:`provenance` (wall time ``line["seconds"]``) to
    ``path`` and print it, without the provenance, as one JSON line."""
    line["provenance"] = provenance(script, argv, line["seconds"])
    append_jsonl(path, line)
    print(json.dumps({k: v for k, v in line.items() if k != "provenance"}, default=str), flush=True)
