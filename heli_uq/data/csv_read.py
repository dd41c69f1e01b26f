"""Reading a rig record CSV: the published format and the variants other writers make.

Which file column holds which quantity is read from the header, in any order:

* each of ``u_theta, u_psi, theta, psi, dt`` by its published cell (``Pitch motor
  $u_\\theta$ [V]``, ...), its short name, or the words that name it (``pitch motor``,
  ``yaw motor``, ``pitch angle``, ``yaw angle``, ``sample time``); case, spaces, TeX
  markup and a trailing unit in brackets are ignored (:data:`COLUMN_NAMES`);
* a first column whose header cell is empty or ``index`` (what a data-frame library writes
  for its row index) is skipped; its cells must be numbers;
* a unit in the cell's trailing brackets must be one of :data:`UNITS`: V (or mV), rad (or
  degrees, converted with a warning), s (or ms); the published header's are V, rad and s;
* a time column (``t``, ``time``, with a unit or not) is checked against the sample time:
  ``t_k = t_0 + k dt`` to :data:`TIME_TOL` of a sample.  A file with a time column needs no
  sample-time column: ``dt`` is then its mean spacing.

The record's times are ``k dt`` from 0 whatever the time column's start (windows are in
seconds from the first sample).  Any other header is refused naming the cell it cannot
place, the quantity it finds twice or the one it misses.
"""

from __future__ import annotations

import csv
import logging
import math
import os
import re
from pathlib import Path

import numpy as np

from heli_uq.data.record import COLUMNS, HEADER, Experiment, _as_float
from heli_uq.errors import DataFormatError

__all__ = ["read_record", "COLUMN_NAMES", "DT_REL_TOL", "DT_RANGE", "PLAUSIBLE", "MAX_ANGLE_STEP",
           "WRAP_RESIDUAL", "TIME_TOL", "DT_DIGITS", "UNITS", "PITCH_LIMIT"]  # fmt: skip

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
PLAUSIBLE = {"u_theta": (1e3, "V"), "u_psi": (1e3, "V"), "theta": (1e4, "rad"), "psi": (1e4, "rad")}
#: An angle that changes by more than this in one sample [rad] has not moved: it was
#: wrapped into a 2π interval by the writer (a rig's yaw turns < 0.1 rad per 0.01 s).
MAX_ANGLE_STEP = math.pi
#: A wrap is a jump within this [rad] of a multiple of 2π; any other jump beyond
#: :data:`MAX_ANGLE_STEP` is refused.
WRAP_RESIDUAL = 0.5
#: A time column's entry may differ from ``t_0 + k dt`` by this fraction of a sample (a
#: writer that rounds its time stamps); beyond it the samples are not evenly spaced.
TIME_TOL = 0.01

#: Significant digits of a sample time taken from a time column's spacing (0.01 s read as
#: 0.010000000000000083 s from times 5.00-5.03 s is 0.01 s).
DT_DIGITS = 12

#: The names a header cell may give each column (after :func:`_cell_key`): a cell naming a
#: quantity equals one of its names or, for names of several words, contains them.
COLUMN_NAMES = {
    "u_theta": ("u_theta", "u_θ", "pitch motor", "pitch voltage"),
    "u_psi": ("u_psi", "u_ψ", "yaw motor", "yaw voltage"),
    "theta": ("theta", "θ", "pitch angle"),
    "psi": ("psi", "ψ", "yaw angle"),
    "dt": ("dt", "δt", "sample time", "sampling time", "time step", "delta t"),
    "time": ("t", "time"),
}
#: The units a header may give each quantity, with the factor to the package's unit (V, rad,
#: s).  An angle in degrees is converted, with a warning; a unit not listed is refused.
UNITS = {
    "u_theta": {"v": 1.0, "volt": 1.0, "volts": 1.0, "mv": 1e-3},
    "theta": {"rad": 1.0, "radian": 1.0, "radians": 1.0, "deg": math.pi / 180, "degree": math.pi / 180,
              "degrees": math.pi / 180, "°": math.pi / 180},
    "dt": {"s": 1.0, "sec": 1.0, "seconds": 1.0, "ms": 1e-3},
}
UNITS.update(u_psi=UNITS["u_theta"], psi=UNITS["theta"], time=UNITS["dt"])
#: First header cells of a row-index column.
INDEX_NAMES = ("", "index")
_MEASURED = COLUMNS[:4]
_TEX = str.maketrans("", "", "$\\{}")


_UNIT = re.compile(r"\s*[\[(]([^\[\]()]*)[\])]$")


def _plain(cell: str) -> str:
    """A header cell lower-cased, without BOM, TeX markup or repeated spaces."""
    return " ".join(cell.replace("\ufeff", "").translate(_TEX).split()).lower()


def _cell_key(cell: str) -> str:
    """:func:`_plain` without a trailing unit (``Pitch motor $u_\\theta$ [V]`` -> ``pitch motor
    u_theta``)."""
    return _UNIT.sub("", _plain(cell))


def _cell_unit(cell: str) -> str | None:
    """The unit a header cell gives in trailing brackets (lower-case), or None."""
    match = _UNIT.search(_plain(cell))
    return None if match is None else match.group(1).strip()


def _roles(cell: str) -> set[str]:
    key = _cell_key(cell)
    return {role for role, names in COLUMN_NAMES.items()
            for name in names if key == name or (" " in name and name in key)}  # fmt: skip


def _columns(header: list[str], fail_header) -> tuple[dict[str, int], dict[str, float]]:
    """``{quantity: file column}`` of a header (``"index"`` for a skipped row index) and
    ``{quantity: factor}`` to the package's units of those whose header gives another unit
    (:data:`UNITS`); ``fail_header(detail)`` makes the error."""
    found: dict[str, int] = {}
    scales: dict[str, float] = {}
    for col, cell in enumerate(header):
        roles = _roles(cell)
        if col == 0 and not roles and _cell_key(cell) in INDEX_NAMES:
            roles = {"index"}
        if len(roles) != 1:
            what = "names no column it knows" if not roles else f"names {' and '.join(sorted(roles))}"
            raise fail_header(f"cell {col + 1} ({cell.strip()!r}) {what}")
        (role,) = roles
        if role in found:
            raise fail_header(f"cells {found[role] + 1} and {col + 1} both name {role}")
        found[role] = col
        unit = _cell_unit(cell)
        if role in UNITS and unit is not None:
            if unit not in UNITS[role]:
                raise fail_header(f"cell {col + 1} ({cell.strip()!r}) gives {role} in {unit!r}; "
                                  f"expected one of {', '.join(UNITS[role])}")  # fmt: skip
            if UNITS[role][unit] != 1.0:
                scales[role] = UNITS[role][unit]
    missing = [r for r in _MEASURED if r not in found]
    if "dt" not in found and "time" not in found:
        missing.append("dt (or a time column)")
    if missing:
        raise fail_header(f"no column for {', '.join(missing)}")
    return found, scales


def read_record(path: str | os.PathLike) -> Experiment:
    """Read a rig record CSV (published format; BOM and CRLF optional; module docstring).

    Parameters
    ----------
    path : str or path-like
        CSV file with a header (module docstring) and at least 2 data rows; the sample
        time is in the first data row, and later rows leave its cell empty, leave it out
        (when it is the last column), or repeat it (to :data:`DT_REL_TOL`).  Angles wrapped
        into a 2π interval by the writer are unwrapped, with a warning.

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
    while rows and not any(cell.strip() for cell in rows[-1][1]):
        rows.pop()  # trailing empty lines
    if not rows:
        raise DataFormatError(f"{path}: empty file, expected a header and data rows")

    line, header = rows[0]
    expected = f"expected {','.join(HEADER)!r} or {','.join(COLUMNS)!r}, in any order"

    def fail_header(detail: str) -> DataFormatError:
        return DataFormatError(f"{path}, line {line}: unexpected header {header}: {detail}; {expected}")

    cells = [c for c in header if c.strip()]
    if len(header) == 1 and ";" in header[0]:
        raise DataFormatError(f"{path}, line {line}: the cells are separated by ';', expected ',' "
                              "(and a decimal point, not a comma): write the file as a comma-separated "
                              "CSV")  # fmt: skip
    if cells and all(_as_float(c) is not None for c in cells):
        raise DataFormatError(f"{path}, line {line}: missing header: found numbers {header} where "
                              f"the header was expected ({expected})")  # fmt: skip
    columns, scales = _columns(header, fail_header)
    for role, factor in scales.items():
        logging.getLogger(__name__).warning(
            f"{path}: column {columns[role] + 1} ({role}) is in {_cell_unit(header[columns[role]])} "
            f"by its header; read in {next(iter(UNITS[role]))} (× {factor:.6g})")
    role_of = {col: role for role, col in columns.items()}
    if len(rows) < 3:
        raise DataFormatError(f"{path}: {len(rows) - 1} data row(s), expected at least 2")

    def fail(line: int, col: int | None, message: str) -> DataFormatError:
        where = f"{path}, line {line}" + ("" if col is None else f", column {col + 1} ({role_of[col]})")
        return DataFormatError(f"{where}: {message}")

    values, times, dt = _read_rows(rows[1:], columns, scales, fail)
    lines = [line for line, _ in rows[1:]]
    if times is not None:
        dt = _check_times(times, dt, lines, columns["time"], fail)
    _unwrap_angles(values, lines, columns, fail, path)
    _check_pitch_range(values[:, 2], columns, path)
    n = values.shape[0]
    return Experiment(np.arange(n) * dt, values[:, :2], values[:, 2:], dt, str(path))


def _read_rows(rows, columns: dict[str, int], scales: dict[str, float], fail):
    """The measured columns (N, 4) in :data:`COLUMNS` order, the time column (N,) or None,
    and the sample time (None without a sample-time column), each in the package's units
    (its header's unit times ``scales``)."""
    width = max(columns.values()) + 1
    dt_last = columns.get("dt") == width - 1
    values = np.empty((len(rows), 4))
    times = np.empty(len(rows)) if "time" in columns else None
    dt = None
    for k, (line, row) in enumerate(rows):
        if k > 0 and dt_last and len(row) == width - 1:
            row = [*row, ""]  # the empty sample-time cell left out (a writer that drops it)
        if len(row) != width:
            raise fail(line, None, f"expected {width} cells"
                       + (f" ({width - 1} after the first data row)" if k > 0 and dt_last else "")
                       + f", found {len(row)}")  # fmt: skip
        for role, col in columns.items():
            cell = row[col]
            if role == "dt" and k > 0 and cell.strip() == "":
                continue
            if cell.strip() == "":
                raise fail(line, col, "expected a number, found an empty cell"
                           + (" (the sample time belongs in the first data row)" if role == "dt" else ""))
            x = _as_float(cell)
            if x is None or not math.isfinite(x):
                raise fail(line, col, f"expected a finite number, found {cell!r}")
            x *= scales.get(role, 1.0)
            if role in PLAUSIBLE:
                limit, unit = PLAUSIBLE[role]
                if abs(x) > limit:
                    raise fail(line, col, f"expected {'a voltage' if unit == 'V' else 'an angle'} within "
                                          f"±{limit:g} {unit}, found {cell!r}")  # fmt: skip
                values[k, _MEASURED.index(role)] = x
            elif role == "time":
                times[k] = x
            elif role == "dt" and k == 0:
                dt = _checked_dt(x, lambda m, line=line, col=col: fail(line, col, m), repr(cell))
            elif role == "dt" and not math.isclose(x, dt, rel_tol=DT_REL_TOL):
                raise fail(line, col, f"sample time {cell!r} differs from {dt!r} in line "
                           f"{rows[0][0]}; expected an empty cell")
    return values, times, dt


def _checked_dt(dt: float, fail, text: str) -> float:
    if not DT_RANGE[0] <= dt <= DT_RANGE[1]:
        raise fail(f"expected a sample time in {DT_RANGE[0]:g}..{DT_RANGE[1]:g} s, found {text}")
    return dt


def _check_times(times: np.ndarray, dt: float | None, lines: list[int], col: int, fail) -> float:
    """The sample time: ``dt``, or without it the time column's mean spacing; either way
    the time column must be ``t_0 + k dt`` to :data:`TIME_TOL` of a sample."""
    k = np.arange(times.size)
    if dt is None:  # to DT_DIGITS: the float noise of the subtraction is not the writer's
        spacing = float(f"{(times[-1] - times[0]) / (times.size - 1):.{DT_DIGITS}g}")
        dt = _checked_dt(spacing, lambda m: fail(lines[-1], col, m + " (the time column's mean "
                                                  "spacing)"), f"{spacing!r} s")  # fmt: skip
    off = np.abs(times - times[0] - k * dt)
    bad = np.flatnonzero(off > TIME_TOL * dt)
    if bad.size:
        j = int(bad[0])
        raise fail(lines[j], col, f"time {float(times[j])!r} s is not {times[0]:g} + {j} × {dt:g} s: "
                   "expected evenly spaced samples")
    return dt


#: A pitch beyond this [rad] is no rig's (it hangs below the horizontal and stops short
#: of the vertical): a column of such angles is most likely in degrees.
PITCH_LIMIT = 0.5 * math.pi


def _check_pitch_range(theta: np.ndarray, columns: dict, path) -> None:
    """Warn, naming the column, when the pitch leaves ±:data:`PITCH_LIMIT` (the model
    calls such a simulation unphysical): an angle logged in degrees under a rad header
    would otherwise be fitted as physics and its misfit blamed on the model."""
    low, high = float(np.min(theta)), float(np.max(theta))
    if max(-low, high) > PITCH_LIMIT:
        logging.getLogger(__name__).warning(
            f"{path}: column {columns['theta'] + 1} (theta) holds pitch angles {low:.4g}..{high:.4g} rad, "
            f"beyond ±{PITCH_LIMIT:.4g} rad (90 deg), where no rig's pitch goes: if the column is in "
            "degrees, write [deg] in its header")


def _unwrap_angles(values: np.ndarray, lines: list[int], columns: dict, fail, path) -> None:
    """Undo, in place, a writer's wrapping of the angles (columns 2, 3 of ``values``) into
    a 2π interval.

    A jump beyond :data:`MAX_ANGLE_STEP` between two samples within :data:`WRAP_RESIDUAL` of
    a multiple of 2π is removed from that sample on, with a warning naming the lines; any
    other such jump raises ``fail(line, column, message)``.
    """
    for j, role in ((2, "theta"), (3, "psi")):
        col = columns[role]
        step = np.diff(values[:, j])
        jumps = np.flatnonzero(np.abs(step) > MAX_ANGLE_STEP)
        if jumps.size == 0:
            continue
        turns = np.round(step[jumps] / (2 * np.pi))
        bad = np.abs(step[jumps] - 2 * np.pi * turns) > WRAP_RESIDUAL
        if bad.any():
            i = int(jumps[bad][0])
            raise fail(lines[i + 1], col, f"jumps by {step[i]:+.3f} rad from the line before: "
                       f"expected less than {MAX_ANGLE_STEP:.3f} rad per sample, or a wrap "
                       f"by a multiple of 2π")
        shift = np.zeros(values.shape[0])
        shift[jumps + 1] = 2 * np.pi * turns
        values[:, j] -= np.cumsum(shift)
        shown = ", ".join(str(lines[i + 1]) for i in jumps[:5]) + (" ..." if jumps.size > 5 else "")
        logging.getLogger(__name__).warning(
            f"{path}: column {col + 1} ({role}) wraps by 2π at {jumps.size} line(s) "
            f"({shown}); read as a continuous angle")
