"""Atomic file writes (write to a temporary file in the same directory, then rename), and
the up-front memory check of a request (:func:`require_memory`), and JSON without
non-finite numbers (:func:`strict_json`)."""

from __future__ import annotations

import math
import os
import pathlib
import tempfile

__all__ = ["atomic_write_bytes", "atomic_write_text", "publish", "read_json_object",
           "format_bytes", "physical_memory", "require_memory", "strict_json"]


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


def format_bytes(n: float) -> str:
    """``1.46e12`` -> ``"1.3 TiB"`` (binary units)."""
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if abs(n) < 1024 or unit == "PiB":
            return f"{n:.3g} {unit}" if unit != "B" else f"{n:.0f} B"
        n /= 1024
    raise AssertionError("unreachable")


def physical_memory() -> int | None:
    """This machine's physical memory [bytes], or None where the OS does not say."""
    try:
        return int(os.sysconf("SC_PAGE_SIZE")) * int(os.sysconf("SC_PHYS_PAGES"))
    except (AttributeError, ValueError, OSError):
        return None


def require_memory(nbytes: float, what: str, hint: str = "") -> None:
    """Refuse a request that would need more than this machine's physical memory.

    Parameters
    ----------
    nbytes : float
        Estimated peak memory of the request [bytes].
    what : str
        The request, starting with the argument that sets it (``"t_end: 1e11 samples"``).
    hint : str
        What to change, appended after a semicolon.

    Raises
    ------
    heli_uq.errors.ParameterError
        ``"<what> would need about 1.3 TiB of memory, more than this machine's 7.6 GiB; <hint>"``.
    """
    from heli_uq.errors import ParameterError

    total = physical_memory()
    if total is not None and nbytes > total:
        tail = f"; {hint}" if hint else ""
        raise ParameterError(f"{what} would need about {format_bytes(nbytes)} of memory, more than "
                             f"this machine's {format_bytes(total)}{tail}")  # fmt: skip


def strict_json(obj):
    """``obj`` (dicts, lists, tuples, numbers, strings, None) with every non-finite float
    (NaN, ±inf) as None: JSON has no such numbers, and Python's ``Infinity`` and ``NaN``
    tokens break other parsers (JavaScript's ``JSON.parse``, jq's strict mode).  Dump the
    result with ``allow_nan=False`` so that a non-finite number left anywhere is an error."""
    if isinstance(obj, dict):
        return {k: strict_json(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [strict_json(v) for v in obj]
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj
