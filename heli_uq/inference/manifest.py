"""The manifest of a resumable sampler run: everything that determines its draws.

A run stores ``manifest.json`` next to its chunks (:class:`~heli_uq.inference.checkpoint.
Checkpoint`): the problem's fingerprint (a sha256 of the record's values in the windows,
the training and test windows, the model description, the priors, the error model, the
coordinates, the substeps; :func:`heli_uq.probability.problem.fingerprint`), the
sampler's settings (sampler, chains, warm-up, draws, chunk, target acceptance, tree
depth, mass-matrix adaptation, seed...) and the versions of the package and of the
libraries whose numerics the draws depend on (heli_uq's with a digest of its source,
:mod:`heli_uq.provenance`).  Resuming compares the saved manifest with
the one of the new call and refuses any difference, naming every differing setting
(:func:`mismatch_message`), so old draws are never reused under new settings.
"""

from __future__ import annotations

import importlib.metadata
import json

from heli_uq.probability.problem import Problem, fingerprint
from heli_uq.provenance import code_version

__all__ = ["MANIFEST_FILE", "LIBRARIES", "library_versions", "run_manifest", "differences",
           "mismatch_message"]  # fmt: skip

#: File name of the manifest, in the chunk directory.
MANIFEST_FILE = "manifest.json"
#: Distributions whose versions are part of the manifest (their numerics make the draws).
LIBRARIES = ("heli_uq", "jax", "jaxlib", "numpyro", "numpy", "emcee")
#: Values longer than this (as JSON) are named but not quoted in a mismatch message.
_QUOTE_MAX = 32


def library_versions() -> dict[str, str | None]:
    """``{distribution: version}`` of :data:`LIBRARIES` (None if not installed); heli_uq's
    own is :func:`heli_uq.provenance.code_version`, the release with a digest of the
    package's source (the release number alone stays the same across commits, and an
    editable install's metadata can be stale), so a resume under edited code is refused."""
    out = {"heli_uq": code_version()}
    for name in LIBRARIES[1:]:
        try:
            out[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            out[name] = None
    return out


def run_manifest(problem: Problem, settings: dict) -> dict:
    """The manifest of a run of ``problem`` with sampler ``settings`` (JSON-normalised:
    tuples become lists, so a manifest equals itself after a round trip through a file)."""
    manifest = {**settings, **fingerprint(problem), "versions": library_versions()}
    return json.loads(json.dumps(manifest, sort_keys=True))


def _flat(manifest: dict) -> dict:
    out = {}
    for key, value in manifest.items():
        if key == "versions" and isinstance(value, dict):
            out.update({f"{name} version": v for name, v in value.items()})
        else:
            out[key] = value
    return out


def differences(saved: dict, now: dict) -> list[str]:
    """Names of the settings whose values differ between two manifests (versions are
    named ``"<library> version"``), in a stable order."""
    a, b = _flat(saved), _flat(now)
    return [k for k in sorted(set(a) | set(b)) if a.get(k) != b.get(k)]


def _change(key: str, old, new) -> str:
    a, b = json.dumps(old), json.dumps(new)
    if max(len(a), len(b)) > _QUOTE_MAX:
        return f"{key} changed"
    return f"{key} {a} -> {b}"


def mismatch_message(saved: dict, now: dict) -> str:
    """One phrase naming each differing setting with its saved and new value, e.g.
    ``"chains 4 -> 2, seed 0 -> 2"``; long values (the model description, the priors, the
    data hash) are named only (``"model changed"``).  Empty if the manifests agree."""
    a, b = _flat(saved), _flat(now)
    return ", ".join(_change(k, a.get(k), b.get(k)) for k in differences(saved, now))
