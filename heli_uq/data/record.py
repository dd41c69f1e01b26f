"""Rig records of the 2-DOF lab helicopter: the :class:`Experiment` type, reading, writing, slicing.

A record is a CSV file in the format published with HelicopterSciML.jl (UTF-8 with a
byte-order mark, CRLF line endings)::

    Pitch motor $u_\\theta$ [V],Yaw motor $u_\\psi$ [V],Pitch angle $\\theta$ [rad],...
    1.2098,0.74441,-0.66698,0.81165,0.01
    1.2098,0.74441,-0.66941,0.82703,
    ...

i.e. columns ``u_theta, u_psi, theta, psi, dt`` where the sample time ``dt`` appears in
the first data row only.  Inputs are zero-order held: ``u[k]`` acts on
``[t_k, t_{k+1})``.  In memory a record is an :class:`Experiment`.
"""

from __future__ import annotations

import csv
import logging
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from heli_uq.errors import DataFormatError, ParameterError
from heli_uq.io import atomic_write_bytes

__all__ = ["COLUMNS", "HEADER", "Experiment", "parse_window", "read_record"]

#: Relative difference at which a repeated sample time counts as a different one (a
#: writer that prints dt on every row may round it).
DT_REL_TOL = 1e-9
#: Sample times a record may have [s]: the rig's is 0.01; outside, a value is a unit or
#: writing error (5e-324 s made every time stamp 0, 1e-300 s a singular fit).
DT_RANGE = (1e-6, 10.0)
#: Largest magnitude of each measured column (voltages [V], angles [rad]) a record may hold:
#: far beyond any rig (its motors take a few volts; 1e4 rad is 1600 turns), so a value
#: above it is a writing error, not a measurement (1e300 in an angle column was read as a
#: wrap of 1.6e299 turns).
PLAUSIBLE = ((1e3, "V"), (1e3, "V"), (1e4, "rad"), (1e4, "rad"))
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

#: An angle that changes by more than this in one sample [rad] has not moved: it was
#: wrapped into a 2π interval by the writer (a rig's yaw turns < 0.1 rad per 0.01 s).
MAX_ANGLE_STEP = math.pi
#: A wrap is a jump within this [rad] of a multiple of 2π; any other jump beyond
#: :data:`MAX_ANGLE_STEP` is refused.
WRAP_RESIDUAL = 0.5

# Relative tolerance on grid arithmetic (time spacing, window edges), in units of dt.
_GRID_RTOL = 1e-6


def _normalise_header_cell(cell: str) -> str:
    return " ".join(cell.replace("\ufeff", "").split()).lower()


_ACCEPTED_HEADERS = {
    tuple(_normalise_header_cell(c) for c in HEADER),
    tuple(_normalise_header_cell(c) for c in COLUMNS),
}


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


def read_record(path: str | os.PathLike) -> Experiment:
    """Read a rig record CSV (published format; BOM and CRLF optional).

    Parameters
    ----------
    path : str or path-like
        CSV file with a header (published or plain ``u_theta,u_psi,theta,psi,dt``) and
        at least 2 data rows; the sample time is in the first data row, and later rows
        leave its cell empty, leave it out, or repeat it (to :data:`DT_REL_TOL`).  Angles
        wrapped into a 2π interval by the writer are unwrapped, with a warning.

    Returns
    -------
    Experiment
        N data rows, ``t = k*dt`` from 0, ``source = str(path)``.

    Raises
    ------
    DataFormatError
        Naming the file, the 1-based line and the column, on any format problem.
    """
    path = Path(path)
    try:
        with open(path, encoding="utf-8-sig", newline="") as f:
            reader = csv.reader(f)
            rows = [(reader.line_num, row) for row in reader]  # (1-based line, cells)
    except FileNotFoundError:
        raise DataFormatError(f"{path}: no such file") from None
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise DataFormatError(f"{path}: cannot read as a UTF-8 CSV file ({exc})") from None

    def fail(line: int, col: int | None, message: str) -> DataFormatError:
        where = f"{path}, line {line}"
        if col is not None:
            where += f", column {col + 1} ({COLUMNS[col]})"
        return DataFormatError(f"{where}: {message}")

    while rows and not any(cell.strip() for cell in rows[-1][1]):
        rows.pop()  # trailing empty lines
    if not rows:
        raise DataFormatError(f"{path}: empty file, expected a header and data rows")

    line, header = rows[0]
    cells = [c for c in header if c.strip()]
    if cells and all(_as_float(c) is not None for c in cells):
        raise fail(line, None, f"missing header: found numbers {header} where the header "
                   f"({','.join(COLUMNS)} or the published one) was expected")
    if tuple(_normalise_header_cell(c) for c in header) not in _ACCEPTED_HEADERS:
        raise fail(line, None, f"unexpected header {header}, expected "
                   f"{','.join(HEADER)!r} or {','.join(COLUMNS)!r}")
    if len(rows) < 3:
        raise DataFormatError(f"{path}: {len(rows) - 1} data row(s), expected at least 2")

    values = np.empty((len(rows) - 1, 4))
    dt = None
    for k, (line, row) in enumerate(rows[1:]):
        if k > 0 and len(row) == len(COLUMNS) - 1:
            row = [*row, ""]  # the empty sample-time cell left out (a writer that drops it)
        if len(row) != len(COLUMNS):
            raise fail(line, None, f"expected {len(COLUMNS)} cells"
                       + (f" ({len(COLUMNS) - 1} after the first data row)" if k > 0 else "")
                       + f", found {len(row)}")
        for col, cell in enumerate(row):
            if col == 4 and k > 0 and cell.strip() == "":
                continue
            if cell.strip() == "":
                raise fail(line, col, "expected a number, found an empty cell"
                           + (" (the sample time belongs in the first data row)" if col == 4
                              else ""))
            x = _as_float(cell)
            if x is None or not math.isfinite(x):
                raise fail(line, col, f"expected a finite number, found {cell!r}")
            if col < 4:
                limit, unit = PLAUSIBLE[col]
                if abs(x) > limit:
                    raise fail(line, col, f"expected {'a voltage' if col < 2 else 'an angle'} within "
                                          f"±{limit:g} {unit}, found {cell!r}")  # fmt: skip
                values[k, col] = x
            elif k == 0:
                if not DT_RANGE[0] <= x <= DT_RANGE[1]:
                    raise fail(line, col, f"expected a sample time in {DT_RANGE[0]:g}..{DT_RANGE[1]:g} s, "
                                          f"found {cell!r}")  # fmt: skip
                dt = x
            elif not math.isclose(x, dt, rel_tol=DT_REL_TOL):
                raise fail(line, col, f"sample time {cell!r} differs from {dt!r} in line "
                           f"{rows[1][0]}; expected an empty cell")
    _unwrap_angles(values, [line for line, _ in rows[1:]], fail, path)
    n = values.shape[0]
    return Experiment(np.arange(n) * dt, values[:, :2], values[:, 2:], dt, str(path))


def _unwrap_angles(values: np.ndarray, lines: list[int], fail, path) -> None:
    """Undo, in place, a writer's wrapping of the angles (columns 2, 3) into a 2π interval.

    A jump beyond :data:`MAX_ANGLE_STEP` between two samples within :data:`WRAP_RESIDUAL` of
    a multiple of 2π is removed from that sample on, with a warning naming the lines; any
    other such jump raises ``fail(line, column, message)``.
    """
    for col in (2, 3):
        step = np.diff(values[:, col])
        jumps = np.flatnonzero(np.abs(step) > MAX_ANGLE_STEP)
        if jumps.size == 0:
            continue
        turns = np.round(step[jumps] / (2 * np.pi))
        bad = np.abs(step[jumps] - 2 * np.pi * turns) > WRAP_RESIDUAL
        if bad.any():
            j = int(jumps[bad][0])
            raise fail(lines[j + 1], col, f"jumps by {step[j]:+.3f} rad from the line before: "
                       f"expected less than {MAX_ANGLE_STEP:.3f} rad per sample, or a wrap "
                       f"by a multiple of 2π")
        shift = np.zeros(values.shape[0])
        shift[jumps + 1] = 2 * np.pi * turns
        values[:, col] -= np.cumsum(shift)
        shown = ", ".join(str(lines[j + 1]) for j in jumps[:5]) + (" ..." if jumps.size > 5 else "")
        logging.getLogger(__name__).warning(
            f"{path}: column {col + 1} ({COLUMNS[col]}) wraps by 2π at {jumps.size} line(s) "
            f"({shown}); read as a continuous angle")
