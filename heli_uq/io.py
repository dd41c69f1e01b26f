"""Atomic file writes (write to a temporary file in the same directory, then rename)."""

from __future__ import annotations

import os
import pathlib
import tempfile

__all__ = ["atomic_write_bytes", "atomic_write_text", "publish", "read_json_object"]


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def publish(tmp, path) -> None:
    """Give ``tmp`` ordinary permissions (0666 less the umask) and rename it to ``path``."""
    os.chmod(tmp, 0o666 & ~_umask())
    os.replace(tmp, path)


def atomic_write_bytes(path, data: bytes) -> pathlib.Path:
    """Write ``data`` to ``path`` so readers see either the old or the new file, never half."""
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        publish(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def atomic_write_text(path, text: str) -> pathlib.Path:
    """Text version of :func:`atomic_write_bytes` (UTF-8)."""
    return atomic_write_bytes(path, text.encode("utf-8"))


def read_json_object(path, what: str) -> dict:
    """Read a JSON object from ``path``; errors name the file, line and column.

    Raises
    ------
    heli_uq.errors.ParameterError
        Missing file, invalid JSON, or a JSON value that is not an object.
    """
    import json

    from heli_uq.errors import ParameterError

    path = os.fspath(path)
    try:
        with open(path, encoding="utf-8-sig") as fh:
            raw = json.load(fh)
    except FileNotFoundError:
        raise ParameterError(f"{path}: no such {what} file") from None
    except json.JSONDecodeError as exc:
        raise ParameterError(
            f"{path}, line {exc.lineno}, column {exc.colno}: invalid JSON ({exc.msg})"
        ) from None
    if not isinstance(raw, dict):
        raise ParameterError(
            f"{path}: expected a JSON object ({what} file), found {type(raw).__name__}"
        )
    return raw
