"""Chunked, resumable sampler output: one helper for NUTS and emcee.

A sampler writes its draws ``chunk`` at a time into ``DIR/<name>/`` together with the
state to continue from, each file atomically, so Ctrl-C or a crash loses at most one
chunk.  The start (MAP, Laplace covariance) and the *settings* that determine the
draws are saved first; :meth:`Checkpoint.resume_info` refuses to continue under
different settings and names the ones that differ.
"""

from __future__ import annotations

import pathlib
import pickle

import jax

from heli_uq.errors import ParameterError
from heli_uq.io import atomic_write_bytes

__all__ = ["Checkpoint"]

_START = "start.pkl"


class Checkpoint:
    """Chunk files of one sampler run in ``directory``.

    Parameters
    ----------
    directory : path
        E.g. ``out/chunks``; created if missing.
    """

    def __init__(self, directory):
        self.directory = pathlib.Path(directory)
        self.directory.mkdir(parents=True, exist_ok=True)

    def _chunk(self, stream: str, index: int) -> pathlib.Path:
        return self.directory / f"{stream}_chunk_{index:05d}.pkl"

    def start_new(self, start_info: dict, settings: dict) -> None:
        """Delete any earlier chunks and save the start and the settings."""
        for f in self.directory.glob("*_chunk_*.pkl"):
            f.unlink()
        payload = {"start": start_info, "settings": dict(settings)}
        atomic_write_bytes(self.directory / _START, pickle.dumps(payload))

    def resume_info(self, settings: dict) -> dict | None:
        """The saved start if a run with the same ``settings`` can be continued, else None.

        Raises
        ------
        ParameterError
            If a saved run exists with different settings (naming each difference).
        """
        path = self.directory / _START
        if not path.exists():
            return None
        with open(path, "rb") as fh:
            payload = pickle.load(fh)
        saved = payload.get("settings", {})
        diff = [f"{k}: saved {saved.get(k)!r}, now {settings.get(k)!r}"
                for k in sorted(set(saved) | set(settings)) if saved.get(k) != settings.get(k)]  # fmt: skip
        if diff:
            raise ParameterError(f"resume: {self.directory} was run with other settings ("
                                 + "; ".join(diff) + "); use the same settings or start again")  # fmt: skip
        return payload["start"]

    def save(self, stream: str, index: int, record: dict) -> None:
        """Write chunk ``index`` of ``stream`` (arrays and the state to continue from)."""
        atomic_write_bytes(self._chunk(stream, index), pickle.dumps(jax.device_get(record)))

    def load(self, stream: str) -> list[dict]:
        """The saved chunks of ``stream``, in order."""
        records = []
        while (f := self._chunk(stream, len(records))).exists():
            with open(f, "rb") as fh:
                records.append(pickle.load(fh))
        return records
