"""The candidate fits of a discovery round: run as independent tasks
(:func:`heli_uq.executor.run_tasks`), saved as they finish under ``out/candidates/``, and
reused by a rerun with the same output directory when the record and the task match."""

from __future__ import annotations

import hashlib
import json
import pathlib

import numpy as np

from heli_uq.data import Experiment
from heli_uq.discovery.candidates import FitTask, fit_and_score
from heli_uq.discovery.score import gap_text
from heli_uq.executor import TaskFailed, run_tasks
from heli_uq.inference.manifest import library_versions
from heli_uq.io import atomic_write_text

__all__ = ["FIT_VERSION", "CandidateStore", "run_round", "task_signature"]

#: Version of a stored candidate fit; a stored fit of another version is fitted again
#: (2: the Laplace draws are importance-resampled before scoring, or the MAP's plug-in
#: predictive when Pareto k rejects them; 3: a term's start grid adds a MAP start, e.g.
#: a dead band between the record's voltage levels; 4: the held-out CRPS is stored beside
#: the log score; 5: a still axis that a friction term holds starts at rate 0; 6: the MAP's
#: substeps cover the viscous damping's decay; 7: a fit pinned at the solver's limit is held
#: at 2 substeps and settled there, ``inference.settle.EDGE_DECREMENT``).
FIT_VERSION = 7


def task_signature(record: Experiment, task: FitTask) -> str:
    """SHA-256 of the record's arrays, every setting of ``task`` that changes its fit, and the
    versions of heli_uq and of the libraries whose numerics make it (as a sampler run's
    manifest, :func:`heli_uq.inference.manifest.library_versions`)."""
    h = hashlib.sha256()
    for a in (record.t, record.u, record.y):
        h.update(np.ascontiguousarray(a, dtype=np.float64).tobytes())
    h.update(json.dumps([task.fit_window, task.score_window, task.effects, task.seed,
                         task.n_starts, task.draws, task.newton_steps, task.guesses, task.off,
                         task.floor, [(n, p.to_json()) for n, p in task.priors], FIT_VERSION,
                         library_versions()],
                        default=float).encode())  # fmt: skip
    return h.hexdigest()


class CandidateStore:
    """Finished candidate fits under ``out/candidates/`` (reused by a rerun).

    One file per model: ``result`` is its latest fit, ``earlier`` the fits of its other
    tasks by signature (a model is fitted twice when a restart refits it from a better
    current model, and a rerun reuses both).
    """

    def __init__(self, out: pathlib.Path):
        self.dir = out / "candidates"
        self.dir.mkdir(parents=True, exist_ok=True)

    def path(self, key: str) -> pathlib.Path:
        return self.dir / (key.replace(":", "-") + ".json")

    def _read(self, key: str) -> dict:
        try:
            stored = json.loads(self.path(key).read_text())
        except (OSError, ValueError):
            return {}
        return stored if isinstance(stored, dict) else {}

    def load(self, key: str, signature: str):
        stored = self._read(key)
        if stored.get("signature") == signature:
            return stored.get("result")
        return stored.get("earlier", {}).get(signature)

    def save(self, key: str, signature: str, result: dict) -> None:
        stored = self._read(key)
        earlier = dict(stored.get("earlier", {}))
        if "signature" in stored and stored["signature"] != signature:
            earlier[stored["signature"]] = stored.get("result")
        earlier.pop(signature, None)
        atomic_write_text(self.path(key), json.dumps({"signature": signature, "result": result,
                                                      "earlier": earlier}))  # fmt: skip


def run_round(tasks: dict, store: CandidateStore, record: Experiment, scheduler, log) -> dict:
    """Fit every task not already stored; ``{key: result}`` (a failed one: ``{"error"}``; a
    stored one has ``reused: True``)."""
    sigs = {k: task_signature(record, t) for k, t in tasks.items()}
    done = {k: r for k in tasks if (r := store.load(k, sigs[k])) is not None}
    if done:
        log(f"reusing {len(done)} stored fit(s): {', '.join(done)}")
    todo = {k: t for k, t in tasks.items() if k not in done}
    count = iter(range(1, len(todo) + 1))

    def finished(key, result):
        step = f"  [{next(count)}/{len(todo)}] {key}:"
        if isinstance(result, TaskFailed):
            log(f"{step} failed ({result['error']})")
            return
        store.save(key, sigs[key], result)
        log(f"{step} fitted in {result['seconds']:.0f} s, held-out "
            f"{gap_text(result['score'], coverage=False)}")  # fmt: skip

    if todo:
        log(f"fitting {len(todo)} model(s) ({'serial' if scheduler == 'serial' else 'Dask'}): "
            f"{', '.join(todo)}")  # fmt: skip
    fresh = run_tasks(fit_and_score, todo, scheduler=scheduler, on_result=finished)
    return {k: {**done[k], "reused": True} if k in done else dict(fresh[k]) for k in tasks}
