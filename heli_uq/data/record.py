"""Rig records of the 2-DOF lab helicopter: the :class:`Experiment` type, writing, slicing.

A record is a CSV file in the format published with HelicopterSciML.jl (UTF-8 with a
byte-order mark, CRLF line endings)::

    Pitch motor $u_\\theta$ [V],Yaw motor $u_\\psi$ [V],Pitch angle $\\theta$ [rad],...
    1.2098,0.74441,-0.66698,0.81165,0.01
    1.2098,0.74441,-0.66941,0.82703,
    ...

i.e. columns ``u_theta, u_psi, theta, psi, dt`` where the sample time ``dt`` appears in
the first data row only.  Inputs are zero-order held: ``u[k]`` acts on
``[t_k, t_{k+1})``.  In memory a record is an :class:`Experiment`; reading a file, and
the variants of the format that are accepted, is :mod:`heli_uq.data.csv_read`.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from heli_uq.errors import DataFormatError, ParameterError
from heli_uq.io import atomic_write_bytes

__all__ = ["COLUMNS", "HEADER", "Experiment", "parse_window"]

#: Short column names, used in error messages and accepted as a plain header.
COLUMNS = ("u_theta", "u_psi", "theta", "psi", "dt")
#: The published header, written verbatim by :meth:`Experiment.to_csv`.
HEADER = (
    r"Pitch motor $u_\theta$ [V]",
    r"Yaw motor $u_\psi$ [V]",
    r"Pitch angle $\theta$ [rad]",
    r"Yaw angle $\psi$ [rad]",
    r"Sample time $\Delta t$ [s]",
)

# Relative tolerance on grid arithmetic (time spacing, window edges), in units of dt.
_GRID_RTOL = 1e-6


def _as_float(text: str) -> float | None:
    """``float(text)`` or None if *text* is not a number."""
    try:
        return float(text)
    except ValueError:
        return None


@dataclass(frozen=True, eq=False)
class Experiment:
    """One rig record on a uniform sample grid.

    Parameters
    ----------
    t : array_like, shape (N,)
        Sample times [s], ``t[k] = t[0] + k*dt``.  ``t[0]`` is 0 for a whole record and
        the absolute record time for a window of it.
    u : array_like, shape (N, 2)
        Motor voltages ``[u_theta, u_psi]`` [V]; ``u[k]`` is held on ``[t_k, t_k + dt)``.
    y : array_like, shape (N, 2)
        Measured angles ``[theta, psi]`` [rad].
    dt : float
        Sample time [s], > 0.
    source : str
        File path or description of where the record comes from.

    The arrays are stored as read-only float64 copies.

    Raises
    ------
    DataFormatError
        On wrong shapes, non-finite values, ``dt <= 0`` or a time grid not spaced by dt.
    """

    t: np.ndarray
    u: np.ndarray
    y: np.ndarray
    dt: float
    source: str = ""

    def __post_init__(self) -> None:
        n = np.shape(self.t)[0] if np.ndim(self.t) == 1 else None
        expected = {"t": (n,), "u": (n, 2), "y": (n, 2)}
        for name, shape in expected.items():
            try:
                arr = np.array(getattr(self, name), dtype=float)
            except (TypeError, ValueError) as exc:
                raise DataFormatError(f"Experiment.{name}: expected numbers ({exc})") from exc
            if n is None or n < 1 or arr.shape != shape:
                raise DataFormatError(
                    f"Experiment.{name}: expected shape {_shape_text(shape)}, found {arr.shape}"
                )
            if not np.all(np.isfinite(arr)):
                raise DataFormatError(f"Experiment.{name}: contains NaN or inf")
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        try:
            dt = float(self.dt)
        except (TypeError, ValueError):
            dt = math.nan
        if not (math.isfinite(dt) and dt > 0):
            raise DataFormatError(f"Experiment.dt: expected a finite number > 0, found {self.dt!r}")
        object.__setattr__(self, "dt", dt)
        object.__setattr__(self, "source", str(self.source))
        if n > 1 and not np.allclose(np.diff(self.t), dt, rtol=0, atol=_GRID_RTOL * dt):
            raise DataFormatError(f"Experiment.t: expected a uniform grid with spacing dt={dt}")

    @property
    def n(self) -> int:
        """Number of samples N."""
        return int(self.t.shape[0])

    @property
    def duration(self) -> float:
        """Covered time ``N*dt`` [s] (the last input is held for one dt after ``t[-1]``)."""
        return self.n * self.dt

    def window(self, start: float, stop: float = math.inf) -> Experiment:
        """Samples with ``start <= t < stop``, keeping the record's absolute times.

        Parameters
        ----------
        start, stop : float
            Window edges [s]; ``stop`` may be ``inf`` (to the end).  Both must lie in
            ``[t[0], t[0] + duration]`` and ``start < stop``.

        Returns
        -------
        Experiment
            The window, M <= N samples, same dt and source.

        Raises
        ------
        ParameterError
            If the window is reversed, empty or outside the record.
        """
        t0, t_end = float(self.t[0]), float(self.t[0]) + self.duration
        tol = _GRID_RTOL * self.dt
        what = f"window {start:g}:{stop:g} s"
        if not (start < stop):
            raise ParameterError(f"{what}: expected start < stop")
        if start < t0 - tol or (stop > t_end + tol and stop != math.inf):
            raise ParameterError(f"{what}: outside the record, which covers {t0:g}:{t_end:g} s")
        # Work on the index grid so that floating point noise in t cannot move an edge.
        i0 = max(0, math.ceil((start - t0) / self.dt - _GRID_RTOL))
        i1 = self.n if stop == math.inf else math.ceil((stop - t0) / self.dt - _GRID_RTOL)
        i1 = min(self.n, i1)
        if i1 <= i0:
            raise ParameterError(f"{what}: contains no sample (dt = {self.dt} s)")
        return self._rows(slice(i0, i1), self.dt)

    def decimate(self, factor: int) -> Experiment:
        """Every ``factor``-th sample, on a grid with sample time ``dt*factor``.

        Rows of u and y are taken as they are (no averaging), so the returned u is held
        over the coarser interval: use the result for plotting or likelihood grids, not
        to re-simulate what happened on the fine grid.

        Parameters
        ----------
        factor : int
            Decimation factor, >= 1.

        Returns
        -------
        Experiment
            ``ceil(N/factor)`` samples, ``t`` and ``dt`` scaled accordingly.
        """
        if isinstance(factor, bool) or not isinstance(factor, int | np.integer) or factor < 1:
            raise ParameterError(f"decimate: expected an integer factor >= 1, found {factor!r}")
        return self._rows(slice(None, None, int(factor)), self.dt * int(factor))

    def _rows(self, rows: slice, dt: float) -> Experiment:
        return Experiment(self.t[rows], self.u[rows], self.y[rows], dt, self.source)

    def to_csv(self, path: str | os.PathLike) -> Path:
        """Write the record in the published format, atomically.

        The file has a BOM, the published header, CRLF line endings, dt in the first data
        row only, and shortest round-trip float text, so :func:`read_record` gives back
        identical u, y and dt.  The format has no time column: ``t`` is read back as
        ``k*dt`` from 0, whatever ``t[0]`` was.

        Parameters
        ----------
        path : str or path-like
            Destination; replaced via a temporary file in the same directory.

        Returns
        -------
        pathlib.Path
            The written path.
        """
        path = Path(path)
        lines = [",".join(HEADER)]
        for k, row in enumerate(np.hstack([self.u, self.y])):
            cells = [repr(float(v)) for v in row]
            cells.append(repr(self.dt) if k == 0 else "")
            lines.append(",".join(cells))
        text = "\r\n".join(lines) + "\r\n"
        return atomic_write_bytes(path, text.encode("utf-8-sig"))


def _shape_text(shape: tuple) -> str:
    return "(" + ", ".join("N" if s is None else str(s) for s in shape) + ")"


def parse_window(text: str) -> tuple[float, float]:
    """Parse a time window ``"a:b"`` or ``"a:"`` (to the end) in seconds.

    Parameters
    ----------
    text : str
        E.g. ``"90:131"`` or ``"12.5:"``.

    Returns
    -------
    tuple of float
        ``(a, b)`` [s] with ``a < b``; ``b`` is ``inf`` for ``"a:"``.

    Raises
    ------
    ParameterError
        If *text* is not of that form.
    """
    form = "expected 'start:stop' or 'start:' in seconds with start < stop, e.g. '90:131'"
    parts = str(text).split(":")
    if len(parts) == 2:
        start = _as_float(parts[0])
        stop = math.inf if parts[1].strip() == "" else _as_float(parts[1])
        if (
            start is not None
            and stop is not None
            and math.isfinite(start)
            and not math.isnan(stop)
            and start < stop
        ):
            return start, stop
    raise ParameterError(f"window {text!r}: {form}")
