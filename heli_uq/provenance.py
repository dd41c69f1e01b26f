"""Which code made a result: the package version and a digest of the package's own source.

``heli_uq.__version__`` changes only at a release, while the code changes with every
commit; a resumed sampler run or a reused discovery fit that compared only the version
would continue under changed code without a word.  :func:`code_version` appends a digest
of the package's source files (every ``.py`` and ``.json`` file under ``heli_uq/``, the
model's stored fits included, by relative path and content), in the form of a PEP 440 local
version label: ``"0.2.0+src.1a2b3c4d5e6f"``.  Sampler manifests
(:mod:`heli_uq.inference.manifest`), discovery's stored fits and the study and SBC result
lines record it, so a result says which code made it and a resume refuses other code.
"""

from __future__ import annotations

import functools
import hashlib
import pathlib

__all__ = ["SOURCE_SUFFIXES", "DIGEST_CHARS", "source_digest", "code_version"]

#: Files whose content is the package's code and data (compiled caches are left out).
SOURCE_SUFFIXES = (".py", ".json")
#: Hex characters of the sha256 kept in the version label (48 bits: a collision between
#: two states of one checkout is not a practical concern).
DIGEST_CHARS = 12
_PACKAGE = pathlib.Path(__file__).resolve().parent


def source_digest(root: pathlib.Path | None = None) -> str:
    """Sha256 (first :data:`DIGEST_CHARS` hex characters) of the package's source files.

    Parameters
    ----------
    root : pathlib.Path or None
        The package directory (None: the imported ``heli_uq``; computed once per process).

    Returns
    -------
    str
        The digest over every file under ``root`` whose suffix is in
        :data:`SOURCE_SUFFIXES`, outside ``__pycache__``, sorted by relative path; each
        file contributes its relative path and its bytes, so a renamed, added or removed
        file changes the digest as an edited one does.
    """
    if root is None:
        return _package_digest()
    return _digest(pathlib.Path(root))


@functools.cache
def _package_digest() -> str:
    return _digest(_PACKAGE)


def _digest(root: pathlib.Path) -> str:
    h = hashlib.sha256()
    files = sorted(p for p in root.rglob("*") if p.suffix in SOURCE_SUFFIXES and p.is_file()
                   and "__pycache__" not in p.parts)  # fmt: skip
    for path in files:
        rel = path.relative_to(root).as_posix().encode()
        data = path.read_bytes()
        h.update(len(rel).to_bytes(8, "little") + rel + len(data).to_bytes(8, "little") + data)
    return h.hexdigest()[:DIGEST_CHARS]


def code_version() -> str:
    """``"<heli_uq.__version__>+src.<source_digest()>"``: the release and the exact code."""
    import heli_uq

    return f"{heli_uq.__version__}+src.{source_digest()}"
