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
import warnings
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


class _SysStreamHandler(logging.StreamHandler):
    """Writes to whatever ``sys.<name>`` (``stdout`` or ``stderr``) is at the time of each
    message, so redirections made after configuration (e.g. a test's capture) are honoured."""

    def __init__(self, name: str):
        self._sys_name = name
        super().__init__(getattr(sys, name))

    @property
    def stream(self):
        return getattr(sys, self._sys_name)

    @stream.setter
    def stream(self, value):  # set by StreamHandler.__init__; always sys.<name> instead
        pass


class _Once(logging.Filter):
    """Passes a message the first time only: a warning repeated word for word (a MAP refitted
    from itself meets the same substep cap each pass) says nothing the first did not."""

    def __init__(self):
        super().__init__()
        self.seen: set[str] = set()

    def filter(self, record: logging.LogRecord) -> bool:
        message = record.getMessage()
        new = message not in self.seen
        self.seen.add(message)
        return new


def configure_cli(quiet: bool) -> None:
    """Show the package's INFO messages on stdout, one line each, or none of them when
    ``quiet``; warnings and errors go to stderr as one line ``warning: <message>`` either
    way (logging's own last-resort output stops as soon as the logger has any handler),
    each distinct warning once.
    arviz's notice of its coming 1.0 refactor (a ``FutureWarning`` of four lines, printed
    on its first import each day) is not shown: it is about arviz, not about the run.
    Idempotent."""
    warnings.filterwarnings("ignore", category=FutureWarning, module="arviz")
    logger = logging.getLogger(LOGGER_NAME)
    for handler in [h for h in logger.handlers if isinstance(h, _SysStreamHandler)]:
        logger.removeHandler(handler)
    logger.setLevel(logging.WARNING if quiet else logging.INFO)
    warning = _SysStreamHandler("stderr")
    warning.setLevel(logging.WARNING)
    warning.setFormatter(_LevelFormatter())
    warning.addFilter(_Once())
    logger.addHandler(warning)
    if not quiet:
        handler = _SysStreamHandler("stdout")
        handler.setFormatter(logging.Formatter("%(message)s"))
        handler.addFilter(lambda record: record.levelno < logging.WARNING)
        logger.addHandler(handler)
