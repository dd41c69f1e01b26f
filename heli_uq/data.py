"""Rig records of the 2-DOF lab helicopter: reading, writing, slicing and synthesis.

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
import math
import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from heli_uq.errors import DataFormatError, ParameterError
from heli_uq.io import atomic_write_bytes

__all__ = [
    "DATA_ENV_VAR",
    "EXPERIMENTAL_FILENAME",
    "EXPERIMENTAL_SHA256",
    "EXPERIMENTAL_URL",
    "COLUMNS",
    "HEADER",
    "SYNTHETIC_PARAMS",
    "SYNTHETIC_X0",
    "STEP_RANGES",
    "Experiment",
    "parse_window",
    "read_record",
    "load_experimental",
    "load_data",
    "synthetic_experiment",
]

EXPERIMENTAL_FILENAME = "Lab-Helicopter_Experimental-data.csv"
EXPERIMENTAL_URL = (
    "https://raw.githubusercontent.com/SciML/HelicopterSciML.jl/"
    "cd75a43cde8e7ec9a09bc349b058aaa98a67d2c2/data/" + EXPERIMENTAL_FILENAME
)
EXPERIMENTAL_SHA256 = "d569026eb9d26a1d668249cfdd1c2b713ff015a181845e9b983a45e505464fd8"
DATA_ENV_VAR = "HELI_UQ_DATA"

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

#: Default parameters of :func:`synthetic_experiment` (fitted-looking values, paper Table 1).
SYNTHETIC_PARAMS: Mapping[str, float] = {
    "r_c": 0.022,
    "h": 0.001,
    "m": 0.72,
    "J_bc": 0.01,
    "J_s": 0.0017,
    "g": 9.81,
    "K_theta_theta": 0.105,
    "K_theta_psi": 0.0017,
    "K_psi_theta": 0.03,
    "K_psi_psi": 0.043,
    "D_theta": 0.014,
    "D_psi": 0.11,
}
#: Default initial state ``(theta, psi, omega_theta, omega_psi)`` [rad, rad, rad/s, rad/s].
SYNTHETIC_X0 = (-0.5, 0.0, 0.0, 0.0)
#: Voltage ranges [V] of the random ``"steps"`` profile: ``(low, high)`` for u_theta, u_psi.
#: Chosen so that, with the Table 1 parameters, pitch stays in -50..-10 deg and yaw within a
#: turn or so, like the real record (u_theta 1.21-1.47 V, u_psi 0.48-1.57 V).  Above
#: u_theta ~1.48 V the Table 1 pitch torque exceeds the largest gravity torque and the
#: model (which has no pitch stops) loops over the top.
STEP_RANGES = ((1.0, 1.45), (0.4, 1.3))
#: Range [s] of the hold time of one step of the ``"steps"`` profile.
STEP_HOLD = (0.5, 3.0)

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
        what = f"window {start}:{stop} s"
        if not (start < stop):
            raise ParameterError(f"{what}: expected start < stop")
        if start < t0 - tol or (stop > t_end + tol and stop != math.inf):
            raise ParameterError(f"{what}: outside the record, which covers {t0}:{t_end} s")
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
        at least 2 data rows; the sample time is in the first data row.

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
        if len(row) != len(COLUMNS):
            raise fail(line, None, f"expected {len(COLUMNS)} cells, found {len(row)}")
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
                values[k, col] = x
            elif k == 0:
                if x <= 0:
                    raise fail(line, col, f"expected a sample time > 0, found {cell!r}")
                dt = x
            elif x != dt:
                raise fail(line, col, f"sample time {cell!r} differs from {dt!r} in line "
                           f"{rows[1][0]}; expected an empty cell")
    n = values.shape[0]
    return Experiment(np.arange(n) * dt, values[:, :2], values[:, 2:], dt, str(path))


def load_experimental(*, data_dir: str | os.PathLike | None = None) -> Experiment:
    """Load the real rig record (13,100 samples at dt = 0.01 s).

    The file is looked up in, in order: *data_dir*; the directory named by the
    environment variable ``HELI_UQ_DATA``; else it is downloaded once (sha256 checked)
    into pooch's cache directory for ``heli_uq``.  Local copies are read without a
    checksum.

    Parameters
    ----------
    data_dir : str or path-like, optional
        Directory containing ``Lab-Helicopter_Experimental-data.csv``.

    Returns
    -------
    Experiment

    Raises
    ------
    DataFormatError
        If the file is missing in the given directory, cannot be downloaded, or is
        malformed.
    """
    if data_dir is None and os.environ.get(DATA_ENV_VAR):
        data_dir = os.environ[DATA_ENV_VAR]
        if not (Path(data_dir) / EXPERIMENTAL_FILENAME).is_file():
            raise DataFormatError(
                f"{DATA_ENV_VAR}={data_dir}: no file {EXPERIMENTAL_FILENAME} in that directory "
                f"(unset {DATA_ENV_VAR} to download it from {EXPERIMENTAL_URL})"
            )
    if data_dir is not None:
        return read_record(Path(data_dir) / EXPERIMENTAL_FILENAME)

    import pooch

    try:
        path = pooch.retrieve(
            EXPERIMENTAL_URL,
            known_hash=f"sha256:{EXPERIMENTAL_SHA256}",
            fname=EXPERIMENTAL_FILENAME,
            path=pooch.os_cache("heli_uq"),
            progressbar=False,
        )
    except Exception as exc:  # network, permission or checksum failure
        raise DataFormatError(
            f"cannot download {EXPERIMENTAL_URL} ({exc}); set {DATA_ENV_VAR} to a directory "
            f"containing {EXPERIMENTAL_FILENAME}"
        ) from exc
    return read_record(path)


def load_data(spec: str) -> Experiment:
    """Load a record from ``"experimental"`` (the real record) or a CSV path.

    Parameters
    ----------
    spec : str
        The keyword ``"experimental"`` or a path to an existing CSV file.

    Returns
    -------
    Experiment

    Raises
    ------
    DataFormatError
        If *spec* is neither the keyword nor an existing file, or the file is malformed.
    """
    if str(spec).strip().lower() == "experimental":
        return load_experimental()
    if Path(spec).is_file():
        return read_record(spec)
    raise DataFormatError(
        f"unknown data source {spec!r}: expected 'experimental' or the path of an existing "
        f"CSV file"
    )


def _step_inputs(n: int, dt: float, rng: np.random.Generator) -> np.ndarray:
    """Random piecewise-constant voltages, shape (n, 2) [V], levels in STEP_RANGES."""
    low, high = np.array(STEP_RANGES).T
    u = np.empty((n, 2))
    k = 0
    while k < n:
        hold = max(1, round(rng.uniform(*STEP_HOLD) / dt))
        u[k : k + hold] = rng.uniform(low, high)
        k += hold
    return u


def synthetic_experiment(
    params: Mapping[str, float] | None = None,
    x0: Sequence[float] | None = None,
    *,
    duration: float = 20.0,
    dt: float = 0.01,
    inputs: str | np.ndarray = "steps",
    noise_std: Sequence[float] = (0.002, 0.002),
    seed: int = 0,
    simulator: Callable | None = None,
) -> Experiment:
    """A seeded synthetic record: simulate the model and add Gaussian measurement noise.

    Parameters
    ----------
    params : mapping, optional
        Model parameters passed to *simulator*; default :data:`SYNTHETIC_PARAMS`.
    x0 : sequence of 4 floats, optional
        Initial state ``(theta, psi, omega_theta, omega_psi)`` [rad, rad/s]; default
        :data:`SYNTHETIC_X0`.
    duration : float
        Length [s]; N = round(duration/dt).  Ignored when *inputs* is an array.
    dt : float
        Sample time [s].
    inputs : {"steps"} or array_like, shape (N, 2)
        ``"steps"``: random voltages in :data:`STEP_RANGES` held for random
        0.5-3 s segments.  An array: voltages ``[u_theta, u_psi]`` [V], zero-order held.
    noise_std : pair of float
        Standard deviations [rad] of the iid Gaussian noise on theta and psi.
    seed : int
        Seed of the numpy Generator drawing inputs and noise; same seed, same record.
    simulator : callable, optional
        ``simulator(params, x0, u, dt) -> (N, 4)`` states on the sample grid; default
        :func:`heli_uq.simulate.simulate`.

    Returns
    -------
    Experiment
        ``t = k*dt``, ``source = "synthetic(seed=...)"``.

    Raises
    ------
    ParameterError
        On invalid duration, dt, inputs or noise_std.
    DataFormatError
        If the simulation has the wrong shape or is not finite.
    """
    if simulator is None:
        from heli_uq.simulate import simulate as simulator
    params = dict(SYNTHETIC_PARAMS if params is None else params)
    x0 = np.array(SYNTHETIC_X0 if x0 is None else x0, dtype=float)
    if not (np.isfinite(dt) and dt > 0):
        raise ParameterError(f"dt: expected a finite number > 0, found {dt!r}")
    noise_std = np.array(noise_std, dtype=float)
    if noise_std.shape != (2,) or not np.all(np.isfinite(noise_std) & (noise_std >= 0)):
        raise ParameterError(f"noise_std: expected 2 finite numbers >= 0, found {noise_std}")
    rng = np.random.default_rng(seed)

    if isinstance(inputs, str):
        if inputs != "steps":
            raise ParameterError(f"inputs {inputs!r}: expected 'steps' or an (N, 2) array")
        n = round(duration / dt) if np.isfinite(duration) else 0
        if n < 2:
            raise ParameterError(f"duration {duration!r}: expected at least 2 samples of {dt} s")
        u = _step_inputs(n, dt, rng)
    else:
        u = np.array(inputs, dtype=float)
        if u.ndim != 2 or u.shape[0] < 2 or u.shape[1] != 2 or not np.all(np.isfinite(u)):
            raise ParameterError(f"inputs: expected a finite (N, 2) array, N >= 2, "
                                 f"found shape {u.shape}")
        n = u.shape[0]

    states = np.asarray(simulator(params, x0, u, dt), dtype=float)
    if states.shape != (n, 4):
        raise DataFormatError(f"simulation: expected shape ({n}, 4), found {states.shape}")
    if not np.all(np.isfinite(states)):
        raise DataFormatError(f"simulation (seed={seed}): non-finite states, e.g. at "
                              f"t = {np.argmax(~np.all(np.isfinite(states), axis=1)) * dt} s")
    y = states[:, :2] + rng.normal(size=(n, 2)) * noise_std
    return Experiment(np.arange(n) * dt, u, y, dt, f"synthetic(seed={seed})")
