"""Progress messages through the standard :mod:`logging` module.

Library code never prints: a long-running function takes ``log=None`` and sends its
progress lines to ``logging.getLogger(<its module>).info`` (:func:`progress_log`), under the
``heli_uq`` logger.  A script chooses what to see with the usual logging configuration
(``logging.basicConfig(level=logging.INFO)``); the ``heli-uq`` command shows INFO lines on
stdout and nothing with ``--quiet`` (:func:`configure_cli`).  Passing any callable as
``log`` (e.g. ``print``) bypasses logging.

Layer 0: imports nothing else of the package.
"""

from __future__ import annotations

import logging
import sys
from collections.abc import Callable

__all__ = ["LOGGER_NAME", "progress_log", "configure_cli"]

#: The package's root logger.
LOGGER_NAME = "heli_uq"


def progress_log(log: Callable[[str], None] | None, name: str) -> Callable[[str], None]:
    """``log`` if given, else the INFO method of the logger ``name`` (a module's ``__name__``)."""
    return log if log is not None else logging.getLogger(name).info


class _LevelFormatter(logging.Formatter):
    """``"warning: <message>"``: the level in lower case, as the CLI's ``error:`` lines."""

    def format(self, record):
        return f"{record.levelname.lower()}: {record.getMessage()}"


class _StderrHandler(logging.StreamHandler):
    """Writes to whatever ``sys.stderr`` is at the time of each message."""

    def __init__(self):
        super().__init__(sys.stderr)

    @property
    def stream(self):
        return sys.stderr

    @stream.setter
    def stream(self, value):  # set by StreamHandler.__init__; always sys.stderr instead
        pass


class _StdoutHandler(logging.StreamHandler):
    """Writes to whatever ``sys.stdout`` is at the time of each message (so redirections made
    after configuration, e.g. by a test's capture, are honoured)."""

    def __init__(self):
        super().__init__(sys.stdout)

    @property
    def stream(self):
        return sys.stdout

    @stream.setter
    def stream(self, value):  # set by StreamHandler.__init__; always sys.stdout instead
        pass


def configure_cli(quiet: bool) -> None:
    """Show the package's INFO messages on stdout, one line each, or none of them when
    ``quiet``; warnings and errors go to stderr as one line ``warning: <message>`` either
    way (logging's own last-resort output stops as soon as the logger has any handler).
    Idempotent."""
    logger = logging.getLogger(LOGGER_NAME)
    for handler in [h for h in logger.handlers if isinstance(h, _StdoutHandler | _StderrHandler)]:
        logger.removeHandler(handler)
    logger.setLevel(logging.WARNING if quiet else logging.INFO)
    warning = _StderrHandler()
    warning.setLevel(logging.WARNING)
    warning.setFormatter(_LevelFormatter())
    logger.addHandler(warning)
    if not quiet:
        handler = _StdoutHandler()
        handler.setFormatter(logging.Formatter("%(message)s"))
        handler.addFilter(lambda record: record.levelno < logging.WARNING)
        logger.addHandler(handler)
