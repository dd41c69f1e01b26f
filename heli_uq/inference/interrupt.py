"""Prompt, clean interrupts and plain progress lines for long computations.

**Interrupts.**  A JAX computation cannot be stopped from Python while it runs: a SIGINT
is only seen when control returns to the interpreter.  Samplers therefore work in short
blocks (seconds) and, inside :func:`deferred_interrupt`, the first SIGINT only sets a
flag; at the next block boundary (a *safe point*) the sampler saves what is finished and
raises :class:`Interrupted`.  A second SIGINT raises :class:`KeyboardInterrupt` at once.

**Progress.**  :class:`Progress` writes one status line per update: rewritten in place
(carriage return) on a terminal, plain lines at most every :data:`PLAIN_EVERY_S` seconds
otherwise, so a log file has no escape codes and does not fill up.
"""

from __future__ import annotations

import contextlib
import signal
import sys
import threading
import time

__all__ = ["Interrupted", "deferred_interrupt", "Progress", "PLAIN_EVERY_S"]

#: Seconds between progress lines when the stream is not a terminal.
PLAIN_EVERY_S = 30.0


class Interrupted(KeyboardInterrupt):
    """SIGINT honoured at a safe point; ``saved`` says what was saved (for the message)."""

    def __init__(self, saved: str):
        super().__init__(saved)
        self.saved = saved


class _Flag:
    requested = False


@contextlib.contextmanager
def deferred_interrupt():
    """Within the block, the first SIGINT sets ``flag.requested`` instead of raising;
    a second one raises :class:`KeyboardInterrupt`.  Yields the flag.  Outside the main
    thread (where handlers cannot be installed) the flag is never set and SIGINT acts
    as usual."""
    flag = _Flag()
    if threading.current_thread() is not threading.main_thread():
        yield flag
        return

    def handler(signum, frame):
        if flag.requested:
            raise KeyboardInterrupt
        flag.requested = True

    previous = signal.signal(signal.SIGINT, handler)
    try:
        yield flag
    finally:
        signal.signal(signal.SIGINT, previous)


class Progress:
    """A status line on ``stream`` (default stderr); ``enabled=False`` writes nothing.

    Parameters
    ----------
    enabled : bool
    stream : file, optional
    """

    def __init__(self, enabled: bool = True, stream=None):
        self.enabled = enabled
        self.stream = sys.stderr if stream is None else stream
        isatty = getattr(self.stream, "isatty", None)
        self.tty = bool(isatty and isatty())
        self._last = -float("inf")
        self._open = False

    def update(self, text: str, *, force: bool = False) -> None:
        """Show ``text``: in place on a terminal; as a new line otherwise, at most every
        :data:`PLAIN_EVERY_S` seconds unless ``force``."""
        if not self.enabled:
            return
        if self.tty:
            self.stream.write("\r" + text + "\033[K")
            self._open = True
        else:
            now = time.monotonic()
            if not force and now - self._last < PLAIN_EVERY_S:
                return
            self._last = now
            self.stream.write(text + "\n")
        self.stream.flush()

    def close(self, text: str | None = None) -> None:
        """End the status line (with a final ``text``, always shown)."""
        if not self.enabled:
            return
        if text is not None:
            self.update(text, force=True)
        if self.tty and self._open:
            self.stream.write("\n")
            self.stream.flush()
        self._open = False
