"""Chunked, resumable sampler output: one helper for NUTS and emcee.

A sampler writes its draws ``chunk`` at a time into ``DIR/<name>/`` together with the
state to continue from, each file atomically, so Ctrl-C or a crash loses at most one
chunk.  The start (MAP, Laplace covariance) and the run's *manifest* (everything that
determines the draws, :mod:`heli_uq.inference.manifest`) are saved first;
:meth:`Checkpoint.resume_info` refuses to continue under a different manifest, naming
the settings that differ, and refuses a resume with nothing to resume.
"""

from __future__ import annotations

import json
import pathlib
import pickle

import jax

from heli_uq.errors import ParameterError
from heli_uq.inference.manifest import MANIFEST_FILE, mismatch_message
from heli_uq.io import atomic_write_bytes, atomic_write_text

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

    def start_new(self, start_info: dict, manifest: dict) -> None:
        """Delete any earlier chunks and save the start and the run's ``manifest``
        (:func:`heli_uq.inference.manifest.run_manifest`, JSON)."""
        for f in self.directory.glob("*_chunk_*.pkl"):
            f.unlink()
        atomic_write_text(self.directory / MANIFEST_FILE, json.dumps(manifest, indent=1, sort_keys=True))
        self.update_start(start_info)

    def update_start(self, start_info: dict) -> None:
        """Save the run's start again, with facts a resume needs that the run found out
        after it started (e.g. a warm-up cut to its time limit)."""
        atomic_write_bytes(self.directory / _START, pickle.dumps({"start": start_info}))

    def manifest(self) -> dict | None:
        """The saved manifest, or None if there is none.

        Raises
        ------
        ParameterError
            If the file is damaged (not a JSON object).
        """
        path = self.directory / MANIFEST_FILE
        if not path.exists():
            return None
        saved = _read(path, lambda f: json.loads(f.read().decode("utf-8")))
        if not isinstance(saved, dict):
            raise ParameterError(f"resume: {path} is damaged (expected a JSON object, found "
                                 f"{type(saved).__name__}); {_AGAIN}")  # fmt: skip
        return saved

    def obstacle(self, manifest: dict) -> str | None:
        """Why a run with ``manifest`` cannot continue the saved one (a phrase: ``"nothing
        to resume"``, ``"a run without a manifest (older heli_uq)"``, or ``"other settings
        (...)"`` naming each differing setting with its saved and new value); None if it can."""
        if not (self.directory / _START).exists():
            return "nothing to resume"
        try:
            saved = self.manifest()
        except ParameterError:
            return "a damaged manifest"
        if saved is None:
            return "a run without a manifest (older heli_uq)"
        diff = mismatch_message(saved, manifest)
        return f"other settings ({diff})" if diff else None

    def resume_info(self, manifest: dict) -> dict:
        """The saved start of a run with the same ``manifest``, to continue it.

        Raises
        ------
        ParameterError
            If there is no saved run to resume, or the saved run's manifest differs
            (one line naming each differing setting with its saved and new value).
        """
        saved = self.manifest()  # a damaged one is said as such (ParameterError)
        why = self.obstacle(manifest)
        if why is not None and saved is not None and (self.directory / _START).exists():
            raise ParameterError(f"resume: the run in {self.directory} was made with {why}; give the "
                                 "same settings, or start again without resuming")  # fmt: skip
        if why is not None:
            raise ParameterError(f"resume: {why} in {self.directory}; start the run without resuming")
        return _read(self.directory / _START, lambda fh: dict(pickle.load(fh)["start"]))

    def save(self, stream: str, index: int, record: dict) -> None:
        """Write chunk ``index`` of ``stream`` (arrays and the state to continue from)."""
        atomic_write_bytes(self._chunk(stream, index), pickle.dumps(jax.device_get(record)))

    def load(self, stream: str) -> list[dict]:
        """The saved chunks of ``stream``, in order."""
        records = []
        while (f := self._chunk(stream, len(records))).exists():
            records.append(_read(f, pickle.load))
        return records


#: What a damaged checkpoint file's message tells the user to do.
_AGAIN = "start the run again without resuming (it replaces the saved files)"


def _read(path: pathlib.Path, reader):
    """``reader(file)`` of ``path`` opened in binary; a file that does not read (cut short,
    overwritten, another format) is a ParameterError naming it, not the reader's error."""
    try:
        with open(path, "rb") as fh:
            return reader(fh)
    except OSError:
        raise
    except Exception as err:  # pickle and json raise many kinds on damaged input
        raise ParameterError(f"resume: {path} is damaged ({type(err).__name__}: "
                             f"{' '.join(str(err).split())[:80]}); {_AGAIN}") from None
