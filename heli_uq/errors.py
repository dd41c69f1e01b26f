"""Exception types raised at the package's boundaries.

Every error that reaches a user names where the problem is (file, line, column or
argument), what was expected and what was found.  The CLI turns any
:class:`HeliUQError` into one line on stderr and a non-zero exit code.
"""

from __future__ import annotations

__all__ = ["HeliUQError", "DataFormatError", "ParameterError"]


class HeliUQError(Exception):
    """Base class of all errors raised deliberately by :mod:`heli_uq`."""


class DataFormatError(HeliUQError, ValueError):
    """A rig record (CSV) or other input file does not have the expected format."""


class ParameterError(HeliUQError, ValueError):
    """A parameter set, initial state or option has an invalid name or value."""
