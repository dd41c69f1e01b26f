"""Tests of heli_uq.data (CSV reading/writing, windows, decimation, loaders) and of the
synthetic records of heli_uq.simulation."""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import pytest

from heli_uq import data
from heli_uq.data import (
    DATA_ENV_VAR,
    EXPERIMENTAL_FILENAME,
    EXPERIMENTAL_SHA256,
    EXPERIMENTAL_URL,
    HEADER,
    Experiment,
    load_data,
    load_experimental,
    parse_window,
    read_record,
)
from heli_uq.errors import DataFormatError, ParameterError
from heli_uq.simulation.synthetic import (
    STEP_HOLD,
    STEP_RANGES,
    SYNTHETIC_PARAMS,
    synthetic_experiment,
)

REPO_ROOT = Path(__file__).resolve().parents[1]
REAL_DIR = Path(os.environ.get(DATA_ENV_VAR) or REPO_ROOT.parent / "shared" / "data")
REAL_FILE = REAL_DIR / EXPERIMENTAL_FILENAME
needs_real = pytest.mark.skipif(
    not REAL_FILE.is_file(), reason=f"real record not found at {REAL_FILE} (set {DATA_ENV_VAR})"
)

TIME_ATOL = 1e-9  # [s] absolute tolerance on sample times computed as k*dt
UNWRAP_ATOL = 1e-12  # [rad] unwrapping adds and removes 2π: a few ulps of 20 rad
NOISE_STD_RTOL = 0.05  # relative error of a std estimated from 2 x 20,000 samples (~0.5% sd)

PLAIN_HEADER = "u_theta,u_psi,theta,psi,dt"
GOOD_ROWS = [
    "1.2098,0.74441,-0.66698,0.81165,0.01",
    "1.2098,0.74441,-0.66941,0.82703,",
    "1.3,0.5,-0.6,0.8,",
    "1.4,0.6,-0.5,0.9,",
]


def write(path: Path, header: str | None, rows: list[str], *, bom=True, eol="\r\n") -> Path:
    lines = ([header] if header is not None else []) + rows
    text = "".join(line + eol for line in lines)
    path.write_bytes(("\ufeff" if bom else "").encode() + text.encode())
    return path


def linear_simulator(params, x0, u, dt):
    """Stand-in simulator: damped linear 2-DOF system, explicit Euler, ZOH inputs."""
    u = np.asarray(u, dtype=float)
    x = np.empty((u.shape[0], 4))
    x[0] = x0
    damping, stiffness, gain = 2.0, 4.0, 0.5
    for k in range(u.shape[0] - 1):
        pos, vel = x[k, :2], x[k, 2:]
        acc = -stiffness * pos - damping * vel + gain * u[k]
        x[k + 1] = np.concatenate([pos + dt * vel, vel + dt * acc])
    return x


def make_experiment(n=100, dt=0.01, t0=0.0) -> Experiment:
    k = np.arange(n)
    u = np.column_stack([1.0 + 0.001 * k, -0.5 + 0.002 * k])
    y = np.column_stack([np.sin(0.1 * k), np.cos(0.1 * k)])
    return Experiment(t0 + k * dt, u, y, dt, "test")


# --------------------------------------------------------------------------- reading/writing


def test_round_trip_is_exact(tmp_path):
    exp = synthetic_experiment(duration=3.0, simulator=linear_simulator, seed=3)
    path = exp.to_csv(tmp_path / "rec.csv")
    back = read_record(path)
    np.testing.assert_array_equal(back.u, exp.u)
    np.testing.assert_array_equal(back.y, exp.y)
    np.testing.assert_array_equal(back.t, exp.t)
    assert back.dt == exp.dt
    assert back.source == str(path)


def test_to_csv_writes_published_format(tmp_path):
    exp = make_experiment(n=3)
    raw = exp.to_csv(tmp_path / "rec.csv").read_bytes()
    assert raw.startswith("\ufeff".encode())
    lines = raw.decode("utf-8-sig").split("\r\n")
    assert lines[0] == ",".join(HEADER)
    assert lines[1].endswith(",0.01")
    assert all(line.endswith(",") for line in lines[2:4])
    assert lines[4] == "" and len(lines) == 5
    assert b"\n" not in raw.replace(b"\r\n", b"")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rec.csv"]  # no temp file left


def test_to_csv_replaces_existing_file(tmp_path):
    path = tmp_path / "rec.csv"
    path.write_text("old")
    make_experiment(n=5).to_csv(path)
    assert read_record(path).n == 5


@pytest.mark.parametrize("bom", [True, False])
@pytest.mark.parametrize("eol", ["\r\n", "\n"])
@pytest.mark.parametrize(
    "header", [",".join(HEADER), PLAIN_HEADER, "  U_Theta , u_PSI,THETA,psi ,  DT", ",".join(
        h.upper().replace(" ", "   ") for h in HEADER)]
)
def test_read_accepts_format_variations(tmp_path, bom, eol, header):
    exp = read_record(write(tmp_path / "r.csv", header, GOOD_ROWS, bom=bom, eol=eol))
    assert exp.n == len(GOOD_ROWS)
    assert exp.dt == 0.01
    np.testing.assert_array_equal(exp.u[0], [1.2098, 0.74441])
    np.testing.assert_array_equal(exp.y[-1], [-0.5, 0.9])
    np.testing.assert_allclose(exp.t, [0.0, 0.01, 0.02, 0.03], rtol=0, atol=TIME_ATOL)


def test_read_accepts_a_sample_time_repeated_with_rounding(tmp_path):
    """A writer that prints dt on every row (e.g. as differences of float times) may round
    it; within DT_REL_TOL it is the same sample time, beyond it the row is refused."""
    from heli_uq.data.csv_read import DT_REL_TOL

    rows = [r.rstrip(",") + ("" if i == 0 else f",{0.01 * (1 + 0.1 * DT_REL_TOL * (-1) ** i)!r}")
            for i, r in enumerate(GOOD_ROWS)]
    assert read_record(write(tmp_path / "r.csv", PLAIN_HEADER, rows)).dt == 0.01
    rows[2] = rows[2].rsplit(",", 1)[0] + f",{0.01 * (1 + 10 * DT_REL_TOL)!r}"
    with pytest.raises(DataFormatError, match="line 4"):
        read_record(write(tmp_path / "r2.csv", PLAIN_HEADER, rows))


def test_read_accepts_later_rows_that_leave_the_sample_time_cell_out(tmp_path):
    """A writer may drop the empty last cell (``1.3,0.5,-0.6,0.8`` for ``1.3,0.5,-0.6,0.8,``):
    after the first data row the four cells are the four signals."""
    rows = [r if i == 0 else r.rstrip(",") for i, r in enumerate(GOOD_ROWS)]
    assert all(r.count(",") == 3 for r in rows[1:])
    exp = read_record(write(tmp_path / "r.csv", PLAIN_HEADER, rows))
    ref = read_record(write(tmp_path / "ref.csv", PLAIN_HEADER, GOOD_ROWS))
    np.testing.assert_array_equal(exp.u, ref.u)
    np.testing.assert_array_equal(exp.y, ref.y)
    assert exp.dt == ref.dt


@pytest.mark.parametrize("col", [2, 3])
def test_read_unwraps_an_angle_a_writer_wrapped_into_two_pi(tmp_path, caplog, col):
    """A yaw that turns 3.5 times (or a pitch that turns over), written wrapped into
    (-π, π] as some simulators and encoders do, is read back as the continuous angle,
    and the warning names the column and the lines where it wrapped."""
    k = np.arange(400)
    y = np.column_stack([-0.6 + 0.001 * k, 0.8 + 0.002 * k])
    y[:, col - 2] = 0.3 + 0.055 * k  # to 22.2 rad: 3.5 turns, 0.055 rad per sample
    exp = Experiment(k * 0.01, np.full((k.size, 2), 1.0), y, 0.01, "test")
    path = exp.to_csv(tmp_path / "spin.csv")
    wrapped = np.angle(np.exp(1j * y[:, col - 2]))
    lines = path.read_text(encoding="utf-8-sig").splitlines()
    for i, value in enumerate(wrapped):
        cells = lines[i + 1].split(",")
        cells[col] = repr(float(value))
        lines[i + 1] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    with caplog.at_level("WARNING", logger="heli_uq"):
        back = read_record(path)
    np.testing.assert_allclose(back.y, y, rtol=0, atol=UNWRAP_ATOL)
    wraps = np.flatnonzero(np.abs(np.diff(wrapped)) > np.pi) + 3  # 1-based line, after the header
    assert wraps.size == 4  # at π, 3π, 5π, 7π
    message = caplog.text
    assert path.name in message and f"({('theta', 'psi')[col - 2]})" in message
    assert f"at 4 line(s) ({', '.join(map(str, wraps))})" in message


def test_read_refuses_a_jump_that_is_not_a_wrap(tmp_path):
    """A 4 rad jump in one sample is neither motion nor a 2π wrap: refused with its line."""
    path = write(tmp_path / "jump.csv", PLAIN_HEADER, _replace(2, "1.3,0.5,-0.6,4.8,"))
    with pytest.raises(DataFormatError) as info:
        read_record(path)
    assert "line 4, column 4 (psi)" in str(info.value)
    assert "+3.973 rad" in str(info.value)


def _assert_same_record(exp, ref):
    np.testing.assert_array_equal(exp.u, ref.u)
    np.testing.assert_array_equal(exp.y, ref.y)
    assert exp.dt == ref.dt and exp.n == ref.n


@pytest.mark.parametrize("order", [(4, 3, 2, 1, 0), (2, 0, 3, 1, 4)])
def test_read_places_columns_by_their_header_in_any_order(tmp_path, order):
    """The header says which column holds what: a writer that orders them otherwise gives
    the same record (published cells and short names alike)."""
    ref = read_record(write(tmp_path / "ref.csv", PLAIN_HEADER, GOOD_ROWS))
    for i, names in enumerate((HEADER, PLAIN_HEADER.split(","))):
        rows = [",".join(r.split(",")[j] for j in order) for r in GOOD_ROWS]
        path = write(tmp_path / f"r{i}.csv", ",".join(names[j] for j in order), rows)
        _assert_same_record(read_record(path), ref)


def test_read_takes_the_columns_named_in_words(tmp_path):
    header = "Pitch voltage (V), Yaw voltage (V), pitch angle [rad], Yaw Angle [rad], sample time [s]"
    ref = read_record(write(tmp_path / "ref.csv", PLAIN_HEADER, GOOD_ROWS))
    _assert_same_record(read_record(write(tmp_path / "r.csv", header, GOOD_ROWS)), ref)


def test_read_skips_the_row_index_a_data_frame_writes(tmp_path):
    """pandas' ``to_csv`` writes its row index as a first column with an empty header cell
    and the missing sample times as empty cells: the same record."""
    pandas = pytest.importorskip("pandas")
    exp = make_experiment(n=50)
    frame = pandas.DataFrame(np.hstack([exp.u, exp.y]), columns=HEADER[:4])
    frame[HEADER[4]] = [exp.dt] + [np.nan] * (exp.n - 1)
    path = tmp_path / "frame.csv"
    frame.to_csv(path)  # index=True by default
    assert path.read_text().startswith(",Pitch motor")
    back = read_record(path)
    np.testing.assert_allclose(back.u, exp.u, rtol=1e-15)
    np.testing.assert_allclose(back.y, exp.y, rtol=1e-15)
    assert back.dt == exp.dt


def test_a_time_column_gives_the_sample_time_or_is_checked_against_it(tmp_path):
    """Without a sample-time column the time column's spacing is the sample time; with
    both, a time stamp off the grid by more than TIME_TOL of a sample is refused with its
    line; one rounded within it is read."""
    from heli_uq.data.csv_read import TIME_TOL

    ref = read_record(write(tmp_path / "ref.csv", PLAIN_HEADER, GOOD_ROWS))
    times = [5.0 + 0.01 * k for k in range(len(GOOD_ROWS))]
    rows = [f"{t!r}," + ",".join(r.split(",")[:4]) for t, r in zip(times, GOOD_ROWS)]
    exp = read_record(write(tmp_path / "t.csv", "time [s],u_theta,u_psi,theta,psi", rows))
    _assert_same_record(exp, ref)
    np.testing.assert_allclose(exp.t, ref.t, rtol=0, atol=TIME_ATOL)  # from 0, as documented
    both = [f"{t!r},{r}" for t, r in zip(times, GOOD_ROWS)]
    both[2] = f"{times[2] + 0.5 * TIME_TOL * 0.01!r}," + GOOD_ROWS[2]
    _assert_same_record(read_record(write(tmp_path / "both.csv", "t," + PLAIN_HEADER, both)), ref)
    both[2] = f"{times[2] + 2 * TIME_TOL * 0.01!r}," + GOOD_ROWS[2]
    with pytest.raises(DataFormatError) as info:
        read_record(write(tmp_path / "off.csv", "t," + PLAIN_HEADER, both))
    assert "line 4, column 1 (time)" in str(info.value) and "evenly spaced" in str(info.value)


def test_angles_in_degrees_by_the_header_are_read_in_radians(tmp_path, caplog):
    """A yaw logged in degrees under a header that says so is converted, with a warning
    naming the column; a unit no quantity of that column has is refused."""
    ref = read_record(write(tmp_path / "ref.csv", PLAIN_HEADER, GOOD_ROWS))
    rows = [",".join(c if j != 3 or c == "" else repr(math.degrees(float(c)))
                     for j, c in enumerate(r.split(","))) for r in GOOD_ROWS]  # fmt: skip
    header = "u_theta [V],u_psi [V],theta [rad],Yaw angle (deg),dt [s]"
    with caplog.at_level("WARNING", logger="heli_uq"):
        exp = read_record(write(tmp_path / "deg.csv", header, rows))
    np.testing.assert_allclose(exp.y, ref.y, rtol=1e-15)
    np.testing.assert_array_equal(exp.u, ref.u)
    assert "column 4 (psi) is in deg" in caplog.text
    with pytest.raises(DataFormatError, match=r"gives theta in 'v'; expected one of rad"):
        read_record(write(tmp_path / "v.csv", "u_theta,u_psi,theta [V],psi,dt", GOOD_ROWS))


def test_a_pitch_no_rig_reaches_is_read_with_a_warning_that_asks_about_degrees(tmp_path, caplog):
    """A pitch column logged in degrees under a rad header (-38 "rad") reads, since the
    file says rad, but the warning names the column and the remedy; the rig's own
    angles give none; a semicolon-separated file is named as such."""
    with caplog.at_level("WARNING", logger="heli_uq"):
        read_record(write(tmp_path / "rad.csv", PLAIN_HEADER, GOOD_ROWS))
    assert "theta" not in caplog.text
    rows = [f"1.2,0.7,{math.degrees(-0.6 - 0.001 * k)!r},0.8," + ("0.01" if k == 0 else "")
            for k in range(4)]  # a slow pitch, in degrees
    with caplog.at_level("WARNING", logger="heli_uq"):
        read_record(write(tmp_path / "deg.csv", PLAIN_HEADER, rows))
    assert "column 3 (theta) holds pitch angles" in caplog.text and "[deg]" in caplog.text
    semicolons = [r.replace(",", ";") for r in GOOD_ROWS]
    with pytest.raises(DataFormatError, match="separated by ';', expected ','"):
        read_record(write(tmp_path / "semi.csv", PLAIN_HEADER.replace(",", ";"), semicolons))


HEADER_CASES = {
    "unknown cell": ("u_theta,u_psi,angle,psi,dt", ["cell 3 ('angle') names no column"]),
    "twice": ("u_theta,u_psi,theta,Pitch angle [rad],dt", ["cells 3 and 4 both name theta"]),
    "missing": ("u_theta,u_psi,theta,dt,", ["cell 5 ('') names no column"]),
    "missing psi": ("u_theta,u_psi,theta,dt", ["no column for psi"]),
    "no sample time": ("u_theta,u_psi,theta,psi", ["no column for dt (or a time column)"]),
    "index not first": ("u_theta,,u_psi,theta,psi,dt", ["cell 2 ('') names no column"]),
}


@pytest.mark.parametrize("case", HEADER_CASES)
def test_read_refuses_a_header_naming_what_it_cannot_place(tmp_path, case):
    header, fragments = HEADER_CASES[case]
    path = write(tmp_path / "h.csv", header, GOOD_ROWS)
    with pytest.raises(DataFormatError) as info:
        read_record(path)
    message = str(info.value)
    assert "h.csv, line 1: unexpected header" in message and "in any order" in message
    for fragment in fragments:
        assert fragment in message


def test_read_ignores_trailing_empty_line(tmp_path):
    path = write(tmp_path / "r.csv", PLAIN_HEADER, GOOD_ROWS + [""])
    assert read_record(path).n == len(GOOD_ROWS)


def _replace(i, text):
    rows = list(GOOD_ROWS)
    rows[i] = text
    return rows


BAD_CASES = {
    # id: (header, rows, expected fragments (besides the file name))
    "empty": (None, [], ["empty"]),
    "header_only": (PLAIN_HEADER, [], ["0 data row", "at least 2"]),
    "one_row": (PLAIN_HEADER, GOOD_ROWS[:1], ["1 data row", "at least 2"]),
    "missing_header": (None, GOOD_ROWS, ["line 1", "missing header"]),
    "wrong_header": ("a,b,c,d,e", GOOD_ROWS, ["line 1", "unexpected header"]),
    "header_4_cols": ("u_theta,u_psi,theta,psi", GOOD_ROWS, ["line 1", "unexpected header"]),
    "too_few_cells": (PLAIN_HEADER, _replace(2, "1.3,0.5,-0.6"), ["line 4", "found 3"]),
    "first_row_without_dt_cell": (PLAIN_HEADER, _replace(0, "1.2,0.7,-0.6,0.8"), ["line 2", "found 4"]),
    "too_many_cells": (PLAIN_HEADER, _replace(1, "1,2,3,4,,5"), ["line 3", "found 6"]),
    "blank_line_inside": (PLAIN_HEADER, _replace(1, ""), ["line 3", "found 0"]),
    "non_numeric": (PLAIN_HEADER, _replace(3, "1.4,0.6,abc,0.9,"), ["line 5", "column 3 (theta)",
                                                                      "'abc'"]),
    "empty_cell": (PLAIN_HEADER, _replace(2, "1.3,,-0.6,0.8,"), ["line 4", "column 2 (u_psi)"]),
    "nan": (PLAIN_HEADER, _replace(1, "1.3,0.5,-0.6,nan,"), ["line 3", "column 4 (psi)", "nan"]),
    "inf": (PLAIN_HEADER, _replace(2, "-inf,0.5,-0.6,0.8,"), ["line 4", "column 1 (u_theta)"]),
    "missing_dt": (PLAIN_HEADER, _replace(0, "1.2,0.7,-0.6,0.8,"), ["line 2", "column 5 (dt)",
                                                                     "first data row"]),
    "zero_dt": (PLAIN_HEADER, _replace(0, "1.2,0.7,-0.6,0.8,0"), ["line 2", "column 5 (dt)",
                                                                   "sample time in 1e-06..10 s"]),
    "negative_dt": (PLAIN_HEADER, _replace(0, "1.2,0.7,-0.6,0.8,-0.01"), ["line 2", "1e-06..10 s"]),
    "denormal_dt": (PLAIN_HEADER, _replace(0, "1.2,0.7,-0.6,0.8,5e-324"), ["line 2", "'5e-324'"]),
    "huge_dt": (PLAIN_HEADER, _replace(0, "1.2,0.7,-0.6,0.8,3600"), ["line 2", "'3600'"]),
    "huge_voltage": (PLAIN_HEADER, _replace(2, "1e300,0.5,-0.6,0.8,"), ["line 4", "column 1 (u_theta)",
                                                                        "within ±1000 V", "'1e300'"]),
    "huge_angle": (PLAIN_HEADER, _replace(2, "1.3,0.5,1e300,0.8,"), ["line 4", "column 3 (theta)",
                                                                     "within ±10000 rad"]),
    "bad_dt": (PLAIN_HEADER, _replace(0, "1.2,0.7,-0.6,0.8,x"), ["line 2", "column 5 (dt)"]),
    "inconsistent_dt": (PLAIN_HEADER, _replace(3, "1.4,0.6,-0.5,0.9,0.02"), ["line 5",
                                                                            "column 5 (dt)"]),
}


@pytest.mark.parametrize("case", BAD_CASES)
def test_read_rejects_bad_input(tmp_path, case):
    header, rows, fragments = BAD_CASES[case]
    path = write(tmp_path / f"bad_{case}.csv", header, rows)
    with pytest.raises(DataFormatError) as info:
        read_record(path)
    message = str(info.value)
    assert path.name in message
    for fragment in fragments:
        assert fragment in message


def test_read_rejects_missing_file(tmp_path):
    with pytest.raises(DataFormatError, match="no such file") as info:
        read_record(tmp_path / "nothere.csv")
    assert "nothere.csv" in str(info.value)


def test_read_rejects_non_utf8(tmp_path):
    path = tmp_path / "latin.csv"
    path.write_bytes(b"u_theta,u_psi,theta,psi,dt\r\n\xff\xfe,1,2,3,4\r\n")
    with pytest.raises(DataFormatError, match="latin.csv"):
        read_record(path)


# --------------------------------------------------------------------------- Experiment


def test_experiment_properties_and_immutability():
    exp = make_experiment(n=50, dt=0.02)
    assert exp.n == 50
    assert exp.duration == pytest.approx(1.0)
    with pytest.raises(ValueError):
        exp.u[0, 0] = 3.0


@pytest.mark.parametrize(
    "change, fragment",
    [
        (dict(u=np.zeros((10, 3))), "Experiment.u"),
        (dict(y=np.zeros((9, 2))), "Experiment.y"),
        (dict(t=np.zeros((10, 1))), "Experiment.t"),
        (dict(y=np.full((10, 2), np.nan)), "NaN"),
        (dict(dt=0.0), "dt"),
        (dict(dt=-1.0), "dt"),
        (dict(t=np.arange(10) * 0.02), "uniform grid"),
    ],
)
def test_experiment_validation(change, fragment):
    fields = dict(t=np.arange(10) * 0.01, u=np.zeros((10, 2)), y=np.zeros((10, 2)), dt=0.01)
    fields.update(change)
    with pytest.raises(DataFormatError, match=fragment):
        Experiment(**fields, source="x")


def test_window_keeps_absolute_times():
    exp = make_experiment(n=100)
    win = exp.window(0.5, 0.8)
    assert win.n == 30
    assert win.t[0] == pytest.approx(0.5, abs=TIME_ATOL)
    assert win.t[-1] == pytest.approx(0.79, abs=TIME_ATOL)
    np.testing.assert_array_equal(win.y, exp.y[50:80])
    np.testing.assert_array_equal(win.u, exp.u[50:80])
    nested = win.window(0.6, math.inf)
    assert nested.n == 20
    assert nested.t[0] == pytest.approx(0.6, abs=TIME_ATOL)
    np.testing.assert_array_equal(nested.y, exp.y[60:80])


def test_window_whole_record_and_between_samples():
    exp = make_experiment(n=10, dt=1.0)
    assert exp.window(0.0, 10.0).n == 10
    assert exp.window(0.5, 3.5).t.tolist() == [1.0, 2.0, 3.0]


@pytest.mark.parametrize(
    "start, stop, fragment",
    [
        (0.5, 0.5, "start < stop"),
        (0.8, 0.5, "start < stop"),
        (-0.1, 0.5, "outside"),
        (0.5, 1.5, "outside"),
        (0.951, 0.959, "no sample"),
        (1.0, math.inf, "no sample"),
    ],
)
def test_window_errors(start, stop, fragment):
    with pytest.raises(ParameterError, match=fragment):
        make_experiment(n=100).window(start, stop)


def test_window_of_window_rejects_times_before_its_start():
    with pytest.raises(ParameterError, match="outside"):
        make_experiment(n=100).window(0.5, 1.0).window(0.2, 0.7)


def test_decimate():
    exp = make_experiment(n=101, t0=2.0).window(2.0, 3.01)
    dec = exp.decimate(10)
    assert dec.n == 11
    assert dec.dt == pytest.approx(0.1)
    np.testing.assert_array_equal(dec.u, exp.u[::10])
    np.testing.assert_array_equal(dec.y, exp.y[::10])
    np.testing.assert_allclose(dec.t, 2.0 + 0.1 * np.arange(11), rtol=0, atol=TIME_ATOL)
    assert exp.decimate(1).n == exp.n


@pytest.mark.parametrize("factor", [0, -2, 1.5, True])
def test_decimate_rejects_bad_factor(factor):
    with pytest.raises(ParameterError, match="factor"):
        make_experiment().decimate(factor)


@pytest.mark.parametrize(
    "text, expected",
    [("90:131", (90.0, 131.0)), (" 1.5 : 2.25 ", (1.5, 2.25)), ("12:", (12.0, math.inf)),
     ("0:1e1", (0.0, 10.0))],
)
def test_parse_window(text, expected):
    assert parse_window(text) == expected


@pytest.mark.parametrize("text", ["", "5", "a:b", "3:2", "2:2", ":5", "1:2:3", "nan:5", "1:nan"])
def test_parse_window_rejects(text):
    with pytest.raises(ParameterError) as info:
        parse_window(text)
    assert repr(text) in str(info.value)
    assert "start:stop" in str(info.value)


# --------------------------------------------------------------------------- real record


@needs_real
def test_real_record():
    exp = load_experimental(data_dir=REAL_DIR)
    assert exp.n == 13100
    assert exp.dt == 0.01
    assert exp.t[-1] == pytest.approx(130.99, abs=TIME_ATOL)
    np.testing.assert_array_equal(exp.u[0], [1.2098, 0.74441])
    np.testing.assert_array_equal(exp.y[0], [-0.66698, 0.81165])
    win = exp.window(*parse_window("90:131"))
    assert win.t[0] == pytest.approx(90.0, abs=TIME_ATOL)
    assert win.n == 4100


@needs_real
def test_real_record_via_env_var_and_load_data(monkeypatch):
    monkeypatch.setenv(DATA_ENV_VAR, str(REAL_DIR))
    exp = load_data("experimental")
    assert exp.n == 13100
    assert exp.source == str(REAL_FILE)


@needs_real
def test_real_record_round_trip(tmp_path):
    exp = read_record(REAL_FILE)
    back = read_record(exp.to_csv(tmp_path / EXPERIMENTAL_FILENAME))
    np.testing.assert_array_equal(back.u, exp.u)
    np.testing.assert_array_equal(back.y, exp.y)
    assert back.dt == exp.dt


def test_env_var_pointing_to_empty_dir(tmp_path, monkeypatch):
    monkeypatch.setenv(DATA_ENV_VAR, str(tmp_path))

    def no_download(*args, **kwargs):
        raise AssertionError("must not download when the env var is set")

    monkeypatch.setattr("pooch.retrieve", no_download)
    with pytest.raises(DataFormatError) as info:
        load_experimental()
    assert DATA_ENV_VAR in str(info.value)
    assert EXPERIMENTAL_FILENAME in str(info.value)


def test_data_dir_argument_wins_over_env_var(tmp_path, monkeypatch):
    monkeypatch.setenv(DATA_ENV_VAR, str(tmp_path / "elsewhere"))
    make_experiment(n=7).to_csv(tmp_path / EXPERIMENTAL_FILENAME)
    assert load_experimental(data_dir=tmp_path).n == 7


def test_data_dir_without_file(tmp_path):
    with pytest.raises(DataFormatError, match="no such file"):
        load_experimental(data_dir=tmp_path)


def test_download_when_nothing_local(tmp_path, monkeypatch):
    monkeypatch.delenv(DATA_ENV_VAR, raising=False)
    cached = make_experiment(n=6).to_csv(tmp_path / EXPERIMENTAL_FILENAME)
    calls = []

    def fake_retrieve(url, known_hash, **kwargs):
        calls.append((url, known_hash, kwargs))
        return str(cached)

    monkeypatch.setattr("pooch.retrieve", fake_retrieve)
    assert load_experimental().n == 6
    assert len(calls) == 1
    url, known_hash, kwargs = calls[0]
    assert url == EXPERIMENTAL_URL
    assert known_hash == f"sha256:{EXPERIMENTAL_SHA256}"
    assert "heli_uq" in str(kwargs["path"])


def test_download_failure_is_a_data_error(monkeypatch):
    monkeypatch.delenv(DATA_ENV_VAR, raising=False)

    def failing(*args, **kwargs):
        raise OSError("network unreachable")

    monkeypatch.setattr("pooch.retrieve", failing)
    with pytest.raises(DataFormatError, match=DATA_ENV_VAR):
        load_experimental()


def test_load_data_path_and_unknown(tmp_path):
    path = make_experiment(n=4).to_csv(tmp_path / "r.csv")
    assert load_data(str(path)).n == 4
    with pytest.raises(DataFormatError, match="unknown data source"):
        load_data(str(tmp_path / "missing.csv"))
    with pytest.raises(DataFormatError, match="unknown data source"):
        load_data("experimentl")


# --------------------------------------------------------------------------- synthetic


def synth(**kwargs):
    return synthetic_experiment(simulator=linear_simulator, **kwargs)


def test_synthetic_reproducible():
    a, b, c = synth(seed=1), synth(seed=1), synth(seed=2)
    np.testing.assert_array_equal(a.u, b.u)
    np.testing.assert_array_equal(a.y, b.y)
    assert not np.array_equal(a.u, c.u)
    assert not np.array_equal(a.y, c.y)
    assert a.source == "synthetic(seed=1)"
    assert a.n == 2000 and a.dt == 0.01


def test_synthetic_step_profile():
    exp = synth(duration=60.0, seed=4)
    for col, (low, high) in enumerate(STEP_RANGES):
        assert np.all((exp.u[:, col] >= low) & (exp.u[:, col] <= high))
    changes = np.flatnonzero(np.any(np.diff(exp.u, axis=0) != 0, axis=1)) + 1
    holds = np.diff(np.concatenate([[0], changes])) * exp.dt
    assert len(holds) >= 60.0 / STEP_HOLD[1]
    assert np.all(holds >= STEP_HOLD[0] - exp.dt) and np.all(holds <= STEP_HOLD[1] + exp.dt)


def test_synthetic_noise_std_recovered():
    noise_std = (0.002, 0.005)
    noisy = synth(duration=200.0, noise_std=noise_std, seed=5)
    clean = synth(duration=200.0, noise_std=(0.0, 0.0), seed=5)
    np.testing.assert_array_equal(noisy.u, clean.u)
    residual = noisy.y - clean.y
    np.testing.assert_allclose(residual.std(axis=0), noise_std, rtol=NOISE_STD_RTOL)
    np.testing.assert_allclose(residual.mean(axis=0), 0.0, atol=NOISE_STD_RTOL * 0.002)


def test_synthetic_passes_defaults_and_array_inputs():
    seen = {}

    def recording(params, x0, u, dt):
        seen.update(params=params, x0=np.array(x0), u=np.array(u), dt=dt)
        return linear_simulator(params, x0, u, dt)

    u = np.column_stack([np.full(30, 1.5), np.linspace(-1, 1, 30)])
    exp = synthetic_experiment(inputs=u, dt=0.02, noise_std=(0, 0), simulator=recording)
    assert seen["params"] == dict(SYNTHETIC_PARAMS)
    np.testing.assert_array_equal(seen["x0"], [-0.5, 0.0, 0.0, 0.0])
    np.testing.assert_array_equal(seen["u"], u)
    assert seen["dt"] == 0.02
    np.testing.assert_array_equal(exp.u, u)
    np.testing.assert_array_equal(exp.y, linear_simulator(None, seen["x0"], u, 0.02)[:, :2])


def test_synthetic_rejects_non_finite_simulation():
    def blowing_up(params, x0, u, dt):
        x = linear_simulator(params, x0, u, dt)
        x[10:] = np.inf
        return x

    with pytest.raises(DataFormatError, match="non-finite"):
        synthetic_experiment(simulator=blowing_up, duration=1.0)


@pytest.mark.parametrize(
    "kwargs",
    [dict(inputs="ramps"), dict(inputs=np.zeros((10, 3))), dict(noise_std=(0.1,)),
     dict(noise_std=(-0.1, 0.1)), dict(dt=0.0), dict(duration=0.0)],
)
def test_synthetic_rejects_bad_options(kwargs):
    with pytest.raises(ParameterError):
        synth(**kwargs)


def test_module_exports():
    assert set(data.__all__) <= set(dir(data))


def test_unseen_inputs_marks_the_samples_whose_voltage_pair_the_other_window_never_holds():
    seen = np.array([[1.2, 0.5], [1.2, 0.5], [1.3, 0.7]])
    u = np.array([[1.2, 0.5], [1.3, 0.5], [1.3, 0.7], [1.2, 0.7], [1.3, 0.5]])
    # each voltage is seen on its own, but (1.3, 0.5) and (1.2, 0.7) are new pairs
    np.testing.assert_array_equal(data.unseen_inputs(seen, u), [False, True, False, True, True])
    assert not data.unseen_inputs(u, u).any()
    assert data.unseen_inputs(np.zeros((0, 2)), u).all()


@needs_real
def test_the_rig_record_test_window_holds_voltage_pairs_its_training_window_never_holds():
    """The published split (train 0-91 s, test 91-131 s): a pitch voltage the training
    window never holds makes every pair it is in new, and the swing the models miss
    (114-121 s, u = (1.451, 1.420) V) is at such a pair."""
    rec = load_experimental(data_dir=REAL_DIR)
    fit, test = rec.t < 91.0 - 1e-9, rec.t >= 91.0 - 1e-9
    new = data.unseen_inputs(rec.u[fit], rec.u[test])
    never_theta = ~np.isin(rec.u[test, 0], rec.u[fit, 0])
    assert never_theta.any() and new[never_theta].all()
    swing = (rec.t[test] >= 115.0) & (rec.t[test] < 120.0)
    assert new[swing].all()
    assert 0 < new.mean() < 1
