"""Tests of the ``heli-uq`` command line interface (heli_uq.cli) and its figures."""

from __future__ import annotations

import json
import math
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from heli_uq.cli import main
from heli_uq.data import EXPERIMENTAL_FILENAME, Experiment, read_record
from heli_uq.errors import ParameterError
from heli_uq.executor import MIN_COMPILE_ENV

REPO_ROOT = Path(__file__).resolve().parents[1]
REAL_DIR = Path(os.environ.get("HELI_UQ_DATA") or REPO_ROOT.parent / "shared" / "data")
REAL_FILE = REAL_DIR / EXPERIMENTAL_FILENAME

HEADER = "t,theta,psi,omega_theta,omega_psi,p_theta,p_psi"
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
PUBLISHED_HEADER = (
    r"Pitch motor $u_\theta$ [V],Yaw motor $u_\psi$ [V],Pitch angle $\theta$ [rad],"
    r"Yaw angle $\psi$ [rad],Sample time $\Delta t$ [s]"
)

# Paper Table 2, written out here independently of heli_uq.model.tables.
J_BC, M, R_C, H, J_S = 0.015, 0.5, 0.015, 0.0, 0.005
TABLE3_X0 = (math.pi / 4, 0.0, -0.1, 0.1)


# --------------------------------------------------------------------------- helpers


def read_sim_csv(path: Path) -> tuple[str, np.ndarray]:
    text = path.read_text(encoding="utf-8")
    header, *rows = text.splitlines()
    values = np.array([[float(c) for c in row.split(",")] for row in rows])
    return header, values


def assert_png(path: Path, min_bytes: int = 10_000) -> None:
    blob = path.read_bytes()
    assert blob[:8] == PNG_MAGIC, f"{path} is not a PNG"
    assert len(blob) > min_bytes, f"{path} is suspiciously small ({len(blob)} bytes)"


def assert_one_line_error(err: str, *needles: str) -> str:
    assert "Traceback" not in err
    lines = err.strip().splitlines()
    assert len(lines) == 1, f"expected one line on stderr, got {err!r}"
    assert lines[0].startswith("heli-uq: error: ")
    for needle in needles:
        assert needle in lines[0], f"{needle!r} not in {lines[0]!r}"
    return lines[0]


def printed_loss(out: str) -> float:
    match = re.search(r"loss V = ([0-9.eE+-]+) rad\^2", out)
    assert match, f"no loss in {out!r}"
    return float(match.group(1))


@pytest.fixture
def small_record(tmp_path) -> Path:
    """A 60-sample record at dt = 0.02 s with voltage steps, in the published format."""
    n, dt = 60, 0.02
    k = np.arange(n)
    u = np.column_stack([np.where(k < 30, 1.30, 1.40), np.where(k < 20, 0.8, 1.1)])
    y = np.column_stack([-0.6 + 0.002 * k, 0.8 + 0.004 * k])
    path = Experiment(k * dt, u, y, dt, "small").to_csv(tmp_path / "small.csv")
    text = path.read_text(encoding="utf-8-sig")
    assert text.splitlines()[0] == PUBLISHED_HEADER  # really the published format
    return path


def run(capsys, *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    captured = capsys.readouterr()
    return code, captured.out, captured.err


# --------------------------------------------------------------------------- simulate table3


@pytest.fixture(scope="module")
def table3_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("table3") / "nested" / "out"  # DIR is created
    code = main(["simulate", "--inputs", "table3", "--out", str(out)])
    return code, out


def test_table3_csv_content(table3_run):
    code, out = table3_run
    assert code == 0
    header, v = read_sim_csv(out / "simulation.csv")
    assert header == HEADER
    dt, t_end = 0.01, 10.0
    assert v.shape == (round(t_end / dt) + 1, 7)
    np.testing.assert_allclose(v[:, 0], np.arange(v.shape[0]) * dt, rtol=0, atol=1e-12)
    # First row is x0 exactly (repr-precision floats round-trip).
    assert tuple(v[0, 1:5]) == TABLE3_X0
    assert np.all(np.isfinite(v))
    # Momenta p = M(theta) v with M from Table 2, computed here independently.
    theta, om_theta, om_psi = v[:, 1], v[:, 3], v[:, 4]
    m11 = J_BC + M * R_C**2 + M * H**2
    np.testing.assert_allclose(v[:, 5], m11 * om_theta, rtol=1e-12, atol=1e-15)
    c, s = np.cos(theta), np.sin(theta)
    m22 = J_BC * c**2 + M * (R_C * c - H * s) ** 2 + J_S
    np.testing.assert_allclose(v[:, 6], m22 * om_psi, rtol=1e-12, atol=1e-15)
    # Velocities are the derivatives of the angles (central differences, O(dt^2)).
    np.testing.assert_allclose(np.gradient(v[:, 1], dt)[1:-1], om_theta[1:-1], atol=2e-3)
    np.testing.assert_allclose(np.gradient(v[:, 2], dt)[1:-1], om_psi[1:-1], atol=2e-3)
    # Zero voltages: pitch falls and settles towards hanging down (theta = -90 deg).
    assert abs(math.degrees(theta[-1]) + 90.0) < 15.0
    assert not (out.parent / ".simulation.csv.tmp").exists()
    assert sorted(p.name for p in out.iterdir()) == ["simulation.csv", "simulation.png"]


def test_table3_png(table3_run):
    _, out = table3_run
    assert_png(out / "simulation.png")


def test_table3_custom_grid_and_summary(tmp_path, capsys):
    code, out, err = run(capsys, "simulate", "--inputs", "table3", "--t-end", "1",
                         "--dt", "0.05", "--out", str(tmp_path))
    assert code == 0, err
    _, v = read_sim_csv(tmp_path / "simulation.csv")
    assert v.shape == (21, 7)
    np.testing.assert_allclose(v[-1, 0], 1.0)
    assert "21 samples" in out and str(tmp_path / "simulation.csv") in out
    assert "loss" not in out  # no measured angles for table3


def test_x0_option(tmp_path, capsys):
    code, _, err = run(capsys, "simulate", "--inputs", "table3", "--t-end", "0.5",
                       "--x0=-0.5,0.25,0,1e-3", "--out", str(tmp_path))
    assert code == 0, err
    _, v = read_sim_csv(tmp_path / "simulation.csv")
    assert tuple(v[0, 1:5]) == (-0.5, 0.25, 0.0, 1e-3)


def test_params_json_changes_trajectory(tmp_path, capsys, table3_run):
    params = tmp_path / "heavy.json"
    params.write_text(json.dumps({"m": 0.9}))
    out = tmp_path / "out"
    code, _, err = run(capsys, "simulate", "--inputs", "table3", "--params", str(params),
                       "--out", str(out))
    assert code == 0, err
    _, heavy = read_sim_csv(out / "simulation.csv")
    _, nominal = read_sim_csv(table3_run[1] / "simulation.csv")
    assert heavy.shape == nominal.shape
    assert tuple(heavy[0, 1:5]) == TABLE3_X0
    assert np.max(np.abs(heavy[:, 1] - nominal[:, 1])) > 1e-2  # [rad]
    # The momenta use the new mass.
    m11 = J_BC + 0.9 * R_C**2
    np.testing.assert_allclose(heavy[:, 5], m11 * heavy[:, 3], rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize(
    ("content", "needles"),
    [
        ('{"mass": 0.5}', ["unknown parameter", "'mass'"]),
        ('{"m": "heavy"}', ["'m'", "must be a number"]),
        ('{"m": -0.5}', ["'m'", "must be > 0"]),
        ('{"m": 0.5,', ["invalid JSON", "line 1"]),
        ("[0.5]", ["JSON object"]),
        ('{"m": [1]}', ["parameter 'm'", "expected a number, found [1]"]),
    ],
    ids=["unknown-name", "non-number", "negative-mass", "invalid-json", "not-object", "a-list"],
)
def test_bad_params_json(tmp_path, capsys, content, needles):
    params = tmp_path / "bad.json"
    params.write_text(content)
    out = tmp_path / "out"
    code, stdout, err = run(capsys, "simulate", "--inputs", "table3", "--params", str(params),
                            "--out", str(out))
    assert code == 2
    assert_one_line_error(err, "bad.json", *needles)
    assert stdout == ""
    assert not (out / "simulation.csv").exists()


def test_missing_params_file(tmp_path, capsys):
    code, _, err = run(capsys, "simulate", "--inputs", "table3", "--params",
                       str(tmp_path / "nope.json"), "--out", str(tmp_path))
    assert code == 2
    assert_one_line_error(err, "nope.json")


@pytest.mark.parametrize("x0", ["1,2,3", "a,b,c,d", "nan,0,0,0", "1,2,3,4,5"])
def test_bad_x0(tmp_path, capsys, x0):
    code, _, err = run(capsys, "simulate", "--inputs", "table3", f"--x0={x0}",
                       "--out", str(tmp_path))
    assert code == 2
    assert_one_line_error(err, "--x0")


@pytest.mark.parametrize(("option", "value"), [("--t-end", "-1"), ("--dt", "0"),
                                                ("--dt", "fast"), ("--t-end", "inf")])
def test_bad_grid_options(tmp_path, capsys, option, value):
    code, _, err = run(capsys, "simulate", "--inputs", "table3", f"{option}={value}",
                       "--out", str(tmp_path))
    assert code == 2
    assert_one_line_error(err, option)


def test_diverging_parameters_exit_1(tmp_path, capsys):
    # Tiny inertias make the damping term D/M11 ~ 1e7 1/s: RK4 at dt = 0.01 s blows up.
    params = tmp_path / "stiff.json"
    params.write_text(json.dumps({"J_bc": 1e-9, "m": 1e-6}))
    code, _, err = run(capsys, "simulate", "--inputs", "table3", "--params", str(params),
                       "--out", str(tmp_path / "out"))
    assert code == 1
    assert "Traceback" not in err
    assert len(err.strip().splitlines()) == 1 and "diverged" in err and "too stiff" in err
    assert not (tmp_path / "out" / "simulation.csv").exists()


@pytest.mark.parametrize(("values", "count"), [({"D_psi": 1e300}, "e+300 substeps"),
                                               ({"J_s": 1e-300, "J_bc": 1e-300}, None)])
def test_absurd_parameters_exit_1_in_one_readable_line(tmp_path, capsys, values, count):
    """A parameter file of absurd values diverges in one line: no numpy ``RuntimeWarning``
    from the stiffness estimate (a rate x/0 is left out), and a substep count of hundreds
    of digits is written as a number a person reads."""
    params = tmp_path / "absurd.json"
    params.write_text(json.dumps(values))
    code, _, err = run(capsys, "simulate", "--inputs", "table3", "--params", str(params),
                       "--out", str(tmp_path / "out"))
    assert code == 1
    assert "Traceback" not in err and "RuntimeWarning" not in err
    (line,) = err.strip().splitlines()
    assert line.startswith("heli-uq: simulation diverged") and "absurd.json" in line
    assert max(len(word) for word in line.split()) < 60  # was a 301-digit count
    if count is not None:
        assert count in line


def test_out_is_a_file(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    code, _, err = run(capsys, "simulate", "--inputs", "table3", "--t-end", "0.1",
                       "--out", str(blocker))
    assert code == 2
    assert_one_line_error(err, str(blocker))


@pytest.mark.parametrize("taken", ["simulation.csv", "simulation.png"])
def test_an_output_path_that_is_a_directory_leaves_no_partial_output(tmp_path, capsys, taken):
    (tmp_path / taken).mkdir()
    code, _, err = run(capsys, "simulate", "--inputs", "table3", "--t-end", "0.1", "--out", str(tmp_path))
    assert code == 2
    assert_one_line_error(err, f"{tmp_path / taken}: a directory where the output file goes")
    assert sorted(p.name for p in tmp_path.iterdir()) == [taken]


def test_usage_errors_exit_2_in_one_line(capsys):
    for argv in ([], ["simulate", "--inputs", "table3"], ["frobnicate"], ["data"],
                 ["sample", "--seed", "1.5", "--out", "o"]):  # fmt: skip
        with pytest.raises(SystemExit) as info:
            main(argv)
        assert info.value.code == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and err.startswith("heli-uq") and "--help')" in err, err


@pytest.mark.parametrize("seed", ["-1", str(2**32), "99999999999999999999999"])
def test_a_seed_numpy_cannot_take_is_refused_in_one_line(tmp_path, capsys, seed):
    with pytest.raises(SystemExit) as info:
        main(["sample", "--seed", seed, "--out", str(tmp_path / "o")])
    assert info.value.code == 2
    assert_one_line_error(capsys.readouterr().err, "--seed", "0..4294967295", seed)
    assert not (tmp_path / "o").exists()


def test_an_exception_no_check_caught_is_one_line_with_status_70(tmp_path, capsys, monkeypatch):
    """A bug reaches the user as one line naming the exception and where it rose (exit 70),
    and as the traceback with HELI_UQ_TRACEBACK set (as the tests set it)."""
    from heli_uq.cli import simulate as simulate_cli
    from heli_uq.cli.main import EXIT_INTERNAL, TRACEBACK_ENV

    def boom(args):
        raise TypeError("unhashable type: 'list'")

    monkeypatch.setattr(simulate_cli, "cmd_simulate", boom)
    argv = ["simulate", "--inputs", "table3", "--out", str(tmp_path / "o")]
    with pytest.raises(TypeError):
        main(argv)
    monkeypatch.delenv(TRACEBACK_ENV)
    assert main(argv) == EXIT_INTERNAL
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert err.startswith("heli-uq: internal error")
    # where: the innermost frame in the package (not in numpy's or JAX's internals)
    assert re.search(r"TypeError: unhashable type: 'list' at main\.py:\d+; set HELI_UQ_TRACEBACK=1", err), err


@pytest.mark.parametrize(("argv", "needles"), [
    (["simulate", "--inputs", "table3", "--out", ""], ["--out", "expected a directory"]),
    (["sample", "--sampler", "laplace", "--target-accept", "0.9"], ["--target-accept", "NUTS only"]),
    (["sample", "--target-accept", "1.5"], ["--target-accept", "(0, 1)", "1.5"]),
    (["sample", "--effects", "yaw:deadband,,"], ["--effects", "an empty item"]),
    (["run", "--resume"], ["--resume: nothing to resume", "posterior"]),
])  # fmt: skip
def test_options_checked_before_any_work(tmp_path, capsys, small_record, argv, needles):
    data = ["--data", str(small_record)] if argv[0] in ("sample", "run") else []
    out = [] if "--out" in argv else ["--out", str(tmp_path / "o")]
    code, stdout, err = run(capsys, *argv, *data, *out)
    assert code == 2 and stdout == ""
    assert_one_line_error(err, *needles)


@pytest.mark.parametrize(("model", "needles"), [
    ({"effects": [], "mechanics": ["closed_form"]}, ["unknown mechanics ['closed_form']"]),
    ({"effects": [{"effect": ["deadband"], "axis": "yaw"}]}, ["unknown effect ['deadband']"]),
    ({"effects": [], "linear_torque": "false"}, ["'linear_torque' must be true or false", "'false'"]),
    ({"effects": [{"effect": "coulomb_friction", "axis": "yaw", "omega_s": "fast"}]},
     ["option 'omega_s': expected a number, found 'fast'"]),
    ({"effects": [{"effect": "coulomb_friction", "axis": "yaw", "kind": "x"}]},
     ["unknown option(s) kind", "expected omega_s"]),
    ({"effects": [{"effect": "neural_torque", "axis": "yaw", "inputs": ["u"]}]},
     ["option 'inputs': expected a string"]),
])  # fmt: skip
def test_a_model_file_of_wrong_types_is_one_line(tmp_path, capsys, model, needles):
    path = tmp_path / "m.json"
    path.write_text(json.dumps(model))
    code, _, err = run(capsys, "simulate", "--inputs", "table3", "--t-end", "0.5", "--model-file", str(path),
                       "--out", str(tmp_path / "o"))  # fmt: skip
    assert code == 2
    assert_one_line_error(err, "m.json", *needles)


# --------------------------------------------------------------------------- simulate record


def test_simulate_record_file(tmp_path, capsys, small_record):
    rec = read_record(small_record)
    out = tmp_path / "out"
    code, stdout, err = run(capsys, "simulate", "--inputs", str(small_record),
                            "--out", str(out))
    assert code == 0, err
    header, v = read_sim_csv(out / "simulation.csv")
    assert header == HEADER
    assert v.shape == (rec.n, 7)
    np.testing.assert_allclose(v[:, 0], np.arange(rec.n) * 0.02, rtol=0, atol=1e-12)
    assert tuple(v[0, 1:5]) == (rec.y[0, 0], rec.y[0, 1], 0.0, 0.0)
    assert np.all(np.isfinite(v))
    # The printed loss is Eq. 1 on the written angles and the record's angles.
    loss = np.mean((v[:, 1] - rec.y[:, 0]) ** 2 + (v[:, 2] - rec.y[:, 1]) ** 2)
    assert printed_loss(stdout) == pytest.approx(loss, rel=1e-5)
    assert f"{rec.n} samples" in stdout
    assert_png(out / "simulation.png")


def test_simulate_record_inputs_matter(tmp_path, capsys, small_record):
    """The record's voltages drive the model: Table 3's zero voltages give another path."""
    code, _, err = run(capsys, "simulate", "--inputs", str(small_record),
                       "--out", str(tmp_path / "rec"))
    assert code == 0, err
    code, _, err = run(capsys, "simulate", "--inputs", "table3", "--t-end", "1.18",
                       "--dt", "0.02", "--x0=-0.6,0.8,0,0", "--out", str(tmp_path / "zero"))
    assert code == 0, err
    _, rec = read_sim_csv(tmp_path / "rec" / "simulation.csv")
    _, zero = read_sim_csv(tmp_path / "zero" / "simulation.csv")
    assert rec.shape == zero.shape
    # Voltages drive the yaw; without voltages and with omega_psi(0) = 0 there is no yaw motion.
    assert abs(rec[-1, 4]) > 0.05
    assert np.all(zero[:, 2] == 0.8) and np.all(zero[:, 4] == 0.0)
    assert np.max(np.abs(rec[:, 1:3] - zero[:, 1:3])) > 1e-3


def test_simulate_record_t_end_truncates(tmp_path, capsys, small_record):
    code, _, err = run(capsys, "simulate", "--inputs", str(small_record), "--t-end", "0.5",
                       "--out", str(tmp_path))
    assert code == 0, err
    _, v = read_sim_csv(tmp_path / "simulation.csv")
    assert v.shape[0] == 25  # t < 0.5 s at dt = 0.02 s
    assert v[-1, 0] < 0.5


def test_simulate_record_rejects_dt_and_long_t_end(tmp_path, capsys, small_record):
    code, _, err = run(capsys, "simulate", "--inputs", str(small_record), "--dt", "0.01",
                       "--out", str(tmp_path))
    assert code == 2
    assert_one_line_error(err, "--dt")
    code, _, err = run(capsys, "simulate", "--inputs", str(small_record), "--t-end", "5",
                       "--out", str(tmp_path))
    assert code == 2
    assert_one_line_error(err, "--t-end", "small.csv")
    # a window of one sample (t < 0.02 s at dt = 0.02 s) is refused as table3's is
    code, _, err = run(capsys, "simulate", "--inputs", str(small_record), "--t-end", "0.02",
                       "--out", str(tmp_path / "one"))
    assert code == 2
    assert_one_line_error(err, "--t-end", "fewer than 2 samples")
    assert not (tmp_path / "one" / "simulation.csv").exists()


def test_simulate_bad_record(tmp_path, capsys):
    bad = tmp_path / "broken_record.csv"
    bad.write_text(PUBLISHED_HEADER + "\n1.2,0.7,-0.6,0.8,0.01\n1.2,oops,-0.6,0.8,\n")
    code, stdout, err = run(capsys, "simulate", "--inputs", str(bad), "--out",
                            str(tmp_path / "out"))
    assert code == 2
    line = assert_one_line_error(err, "broken_record.csv", "'oops'")
    assert "line 3" in line
    assert stdout == ""


def test_simulate_missing_record(tmp_path, capsys):
    code, _, err = run(capsys, "simulate", "--inputs", str(tmp_path / "absent.csv"),
                       "--out", str(tmp_path))
    assert code == 2
    assert_one_line_error(err, "absent.csv")


@pytest.fixture
def real_data(monkeypatch):
    monkeypatch.setenv("HELI_UQ_DATA", str(REAL_DIR))
    if not REAL_FILE.is_file():
        pytest.skip(f"real record not found at {REAL_FILE} (set HELI_UQ_DATA)")
    return read_record(REAL_FILE)


def test_simulate_experiment(tmp_path, capsys, real_data):
    code, stdout, err = run(capsys, "simulate", "--inputs", "experiment", "--t-end", "2",
                            "--out", str(tmp_path))
    assert code == 0, err
    _, v = read_sim_csv(tmp_path / "simulation.csv")
    assert v.shape == (200, 7)
    assert tuple(v[0, 1:5]) == (real_data.y[0, 0], real_data.y[0, 1], 0.0, 0.0)
    assert (v[0, 1], v[0, 2]) == (-0.66698, 0.81165)  # first row of the published file
    loss = np.mean(np.sum((v[:, 1:3] - real_data.y[:200]) ** 2, axis=1))
    assert printed_loss(stdout) == pytest.approx(loss, rel=1e-5)
    assert_png(tmp_path / "simulation.png")


# --------------------------------------------------------------------------- data show


def test_data_show_small(tmp_path, capsys, small_record):
    code, stdout, err = run(capsys, "data", "show", str(small_record), "--out",
                            str(tmp_path / "d"))
    assert code == 0, err
    assert_png(tmp_path / "d" / "data.png")
    assert "N = 60" in stdout and "dt = 0.02 s" in stdout
    assert "1.3..1.4 V" in stdout  # u_theta range
    assert len(stdout.strip().splitlines()) == 1


def test_data_show_window(tmp_path, capsys, small_record):
    code, stdout, err = run(capsys, "data", "show", str(small_record), "--window", "0.2:0.6",
                            "--out", str(tmp_path))
    assert code == 0, err
    assert "N = 20" in stdout


@pytest.mark.parametrize("quiet", [False, True])
def test_a_package_warning_reaches_stderr_as_one_line(tmp_path, capsys, quiet):
    """The reader's warning on a wrapped yaw is shown, quiet or not, as one stderr line
    (with a handler on the package logger, logging's own last-resort output is off)."""
    k = np.arange(300)
    y = np.column_stack([-0.6 + 0 * k, np.angle(np.exp(1j * (0.3 + 0.03 * k)))])
    path = Experiment(k * 0.01, np.full((k.size, 2), 1.0), y, 0.01, "w").to_csv(tmp_path / "w.csv")
    code, stdout, err = run(capsys, "data", "show", str(path), "--out", str(tmp_path / "d"),
                            *(["--quiet"] if quiet else []))
    assert code == 0, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("warning: ") and "(psi) wraps by 2π" in lines[0]
    assert quiet or "psi 17.19..531.1 deg" in stdout  # read continuous: 0.3 + 0.03 * 299 rad



def test_a_warning_repeated_word_for_word_is_shown_once(capsys):
    """A MAP refitted from itself (discover settling a base model held at the solver's
    limit) met the same substep cap at each pass, and the command printed the same
    500-character warning three times.  The command's stderr shows each distinct warning
    once; another message, however close, is shown."""
    import logging

    from heli_uq.log import configure_cli

    configure_cli(True)
    logger = logging.getLogger("heli_uq.simulation.stiffness")
    for message in ("the MAP needs 4 substeps", "the MAP needs 4 substeps", "the MAP needs 8 substeps"):
        logger.warning(message)
    lines = capsys.readouterr().err.splitlines()
    assert lines == ["warning: the MAP needs 4 substeps", "warning: the MAP needs 8 substeps"], lines


@pytest.mark.parametrize("configured", [False, True])
def test_arviz_daily_notice_is_not_shown_by_the_command(tmp_path, configured):
    """arviz prints a four-line FutureWarning on its first import each day (its stamp file
    lives in the user cache); the command's output setup keeps it off stderr.  Without
    that setup the same import shows it, so the check can fail."""
    setup = "from heli_uq.log import configure_cli; configure_cli(True); " if configured else ""
    env = {**os.environ, "XDG_CACHE_HOME": str(tmp_path)}  # no stamp: arviz warns today
    done = subprocess.run([sys.executable, "-c", setup + "import arviz"], env=env,
                          capture_output=True, text=True, timeout=120)  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert ("ArviZ is undergoing" in done.stderr) is not configured

@pytest.mark.parametrize("window", ["2:3", "0.5:0.1", "abc"])
def test_data_show_bad_window(tmp_path, capsys, small_record, window):
    code, _, err = run(capsys, "data", "show", str(small_record), "--window", window,
                       "--out", str(tmp_path))
    assert code == 2
    assert_one_line_error(err, "window")
    assert not (tmp_path / "data.png").exists()


def test_data_show_experimental(tmp_path, capsys, real_data):
    code, stdout, err = run(capsys, "data", "show", "experimental", "--window", "90:131",
                            "--out", str(tmp_path))
    assert code == 0, err
    assert "N = 4100" in stdout
    assert_png(tmp_path / "data.png")


# --------------------------------------------------------------------------- processes


def test_console_script_and_module(tmp_path, small_record):
    script = shutil.which("heli-uq") or str(Path(sys.executable).parent / "heli-uq")
    if not Path(script).is_file():
        pytest.skip("console script heli-uq is not installed")
    done = subprocess.run([script, "--help"], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0
    assert "simulate" in done.stdout and "data" in done.stdout

    done = subprocess.run([script, "simulate", "--inputs", "table3"], capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 2 and "--out" in done.stderr

    out = tmp_path / "proc"
    done = subprocess.run(
        [sys.executable, "-m", "heli_uq.cli", "data", "show", str(small_record),
         "--out", str(out)],
        capture_output=True, text=True, timeout=300,
    )
    assert done.returncode == 0, done.stderr
    assert_png(out / "data.png")

    done = subprocess.run(
        [sys.executable, "-m", "heli_uq.cli", "data", "show", str(tmp_path / "none.csv"),
         "--out", str(out)],
        capture_output=True, text=True, timeout=300,
    )
    assert done.returncode == 2
    assert_one_line_error(done.stderr, "none.csv")


# --------------------------------------------------------------------------- models


def test_simulate_with_effects_and_model_file(tmp_path, capsys, small_record):
    """--effects and --model-file build the same model; effect parameters come from
    --params; the effect changes the trajectory."""
    params = tmp_path / "p.json"
    params.write_text('{"T_0_yaw": 0.01}')
    outs = {}
    for name, option in (("base", []), ("effects", ["--effects", "yaw:torque_offset"]),
                         ("file", ["--model-file", str(tmp_path / "m.json")])):  # fmt: skip
        (tmp_path / "m.json").write_text('{"effects": [{"effect": "torque_offset", "axis": "yaw"}]}')
        extra = [] if name == "base" else ["--params", str(params)]
        code, out, err = run(capsys, "simulate", "--inputs", str(small_record), *option, *extra,
                             "--out", str(tmp_path / name))  # fmt: skip
        assert code == 0, err
        outs[name] = read_sim_csv(tmp_path / name / "simulation.csv")[1]
    np.testing.assert_array_equal(outs["effects"], outs["file"])
    assert np.max(np.abs(outs["effects"][:, 2] - outs["base"][:, 2])) > 1e-4  # psi moved


@pytest.mark.parametrize(
    ("argv", "needles"),
    [
        (["--effects", "yaw:backlash"], ["--effects", "unknown effect 'backlash'", "coulomb_friction",
                                            "heli_uq/model/terms/__init__.py"]),
        (["--effects", "roll:deadband"], ["--effects", "unknown axis 'roll'", "pitch, yaw"]),
        (["--effects", "deadband"], ["--effects", "AXIS:EFFECT"]),
        (["--model-file", "MODEL"], ["m.json", "unknown effect 'spring'"]),
        (["--effects", "yaw:coulomb_friction", "--prior", "F_c_yaw=normal:0:0.01"],
         ["F_c_yaw", "outside its support", "halfnormal"]),
        (["--effects", "yaw:coulomb_friction", "--fix", "F_c_yaw=-0.01"], ["F_c_yaw", ">= 0"]),
        (["--prior", "F_c_yaw=halfnormal:0.01"], ["unknown name 'F_c_yaw'"]),
        (["--prior", "m=lognormal:-1:1"], ["m", "median > 0"]),
        (["--effects", "yaw:deadband", "--model-file", "MODEL"], ["one of them"]),
        (["--effects", "yaw:deadband,yaw:deadband"], ["--effects: deadband(yaw) and deadband(yaw) both"]),
    ],
    ids=["effect", "axis", "form", "model-file", "prior-support", "fix-support", "prior-name",
         "prior-value", "both", "twice"],
)  # fmt: skip
def test_bad_models_and_priors_are_one_line(tmp_path, capsys, small_record, argv, needles):
    model_file = tmp_path / "m.json"
    model_file.write_text('{"effects": ["yaw:spring"]}')
    argv = [str(model_file) if a == "MODEL" else a for a in argv]
    code, stdout, err = run(capsys, "sample", "--data", str(small_record), *argv,
                            "--out", str(tmp_path / "o"))  # fmt: skip
    assert code == 2
    assert_one_line_error(err, *needles)


def test_init_is_the_first_map_start_and_a_bad_one_is_one_line(tmp_path, capsys, small_record,
                                                                monkeypatch):
    """``--init FILE.json`` reaches the MAP as its first guess with the file's names only (the
    MAP start fills in the model's start values: a default of an effect, 0, can sit on a
    bound where no fit starts); an unknown name in it is refused in one line that names
    the file.  ``--init DIR`` reads an earlier run's ``DIR/map.json``, and a directory
    without one is refused in one line."""
    from heli_uq.output import posterior_study

    seen = {}

    def fake_sample_posterior(record, out, **kwargs):
        seen.update(kwargs)
        raise ParameterError("stopped by the test")

    monkeypatch.setattr(posterior_study, "sample_posterior", fake_sample_posterior)
    init = tmp_path / "fit.json"
    init.write_text('{"J_s": 0.00025, "F_c_yaw": 0.013}')
    argv = ["sample", "--data", str(small_record), "--effects", "yaw:coulomb_friction",
            "--out", str(tmp_path / "o")]  # fmt: skip
    code, _, err = run(capsys, *argv, "--init", str(init))
    assert code == 2 and "stopped by the test" in err
    (guess,) = seen["guesses"]
    assert guess == {"J_s": 0.00025, "F_c_yaw": 0.013}  # not completed with the defaults
    run_dir = tmp_path / "friction_run"  # an earlier run's --out directory: its map.json
    run_dir.mkdir()
    code, _, err = run(capsys, *argv, "--init", str(run_dir))
    assert code == 2
    assert_one_line_error(err, "--init", "friction_run", "map.json")
    (run_dir / "map.json").write_text('{"J_s": 0.0003, "F_c_yaw": 0.02}')
    seen.clear()
    code, _, err = run(capsys, *argv, "--init", str(run_dir))
    assert code == 2 and "stopped by the test" in err
    assert seen["guesses"] == [{"J_s": 0.0003, "F_c_yaw": 0.02}]
    init.write_text('{"J_s": 0.00025, "F_s_yaw": 0.002}')  # not a parameter of this model
    code, _, err = run(capsys, *argv, "--init", str(init))
    assert code == 2
    assert_one_line_error(err, "fit.json", "F_s_yaw")


def test_commands_keep_compiled_programs_on_disk(tmp_path):
    """A command writes its compiled programs to ``~/.cache/heli_uq/jax`` (here a temporary
    home), or to ``JAX_COMPILATION_CACHE_DIR`` when that is set; a second run reads them.
    No minimum compile time is set here: the package keeps the fast-compiling programs
    (under JAX's default of 1 s none of this command's are written)."""
    drop = ("JAX_COMPILATION_CACHE_DIR", MIN_COMPILE_ENV)
    env = {k: v for k, v in os.environ.items() if k not in drop}
    env.update(HOME=str(tmp_path / "home"))
    cache = tmp_path / "home" / ".cache" / "heli_uq" / "jax"
    command = [sys.executable, "-m", "heli_uq.cli", "simulate", "--inputs", "table3", "--quiet"]
    done = subprocess.run([*command, "--out", str(tmp_path / "a")], env=env, capture_output=True,
                          text=True, timeout=300)  # fmt: skip
    assert done.returncode == 0, done.stderr
    entries = {p.name for p in cache.iterdir()}
    assert entries, "nothing was written to the compilation cache"
    done = subprocess.run([*command, "--out", str(tmp_path / "b")], env=env, capture_output=True,
                          text=True, timeout=300)  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert {p.name for p in cache.iterdir()} == entries  # the same programs: read, not added
    other = tmp_path / "other"
    done = subprocess.run([*command, "--out", str(tmp_path / "c")], capture_output=True, text=True,
                          env={**env, "JAX_COMPILATION_CACHE_DIR": str(other)}, timeout=300)  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert any(other.iterdir()) and {p.name for p in cache.iterdir()} == entries


def test_the_cache_keeps_a_minimum_compile_time_the_user_set(monkeypatch):
    """The package's minimum compile time for cached programs (0 s) applies only where the
    user set none: a value in the environment, or one this process's JAX already has, is
    kept (and exported for spawned workers as it was)."""
    import jax

    from heli_uq.executor import MIN_COMPILE_SECONDS, use_compilation_cache

    option = "jax_persistent_cache_min_compile_time_secs"
    before = getattr(jax.config, option)
    try:
        for env, configured, expected in ((None, 1.0, MIN_COMPILE_SECONDS), ("2.5", 1.0, 1.0),
                                          (None, 3.0, 3.0)):  # fmt: skip
            if env is None:
                monkeypatch.delenv(MIN_COMPILE_ENV, raising=False)
            else:
                monkeypatch.setenv(MIN_COMPILE_ENV, env)
            jax.config.update(option, configured)
            use_compilation_cache()
            assert getattr(jax.config, option) == expected, (env, configured)
            assert os.environ.get(MIN_COMPILE_ENV) == (env or (repr(MIN_COMPILE_SECONDS) if configured == 1.0
                                                               else None)), (env, configured)  # fmt: skip
    finally:
        jax.config.update(option, before)


EMPTY_CACHE_ENTRY_SCRIPT = """
import pathlib, sys
import heli_uq  # its JAX settings, the cache warning's filter among them
import jax
import jax.numpy as jnp

cache = pathlib.Path(sys.argv[1])
jax.config.update("jax_compilation_cache_dir", str(cache))
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
f = jax.jit(lambda x: jnp.sin(x) * 3.0 + 1.0)
first = float(f(0.5))
entries = [p for p in cache.iterdir() if p.name.endswith("-cache")]
assert entries, sorted(p.name for p in cache.iterdir())
for p in entries:
    p.write_bytes(b"")  # what a reader sees while another process writes the entry
jax.clear_caches()
print(first, float(f(0.5)))
"""


def test_a_cache_entry_read_while_another_process_writes_it_is_compiled_again_without_a_word(tmp_path):
    """JAX writes a persistent cache entry in place, so a process reading it meanwhile finds
    it empty (the two CI workers did); JAX compiles again and warns.  Under ``-W error`` the
    warning would be an exception: ``heli_uq`` silences it, and the result is unchanged."""
    script = tmp_path / "empty_entry.py"
    script.write_text(EMPTY_CACHE_ENTRY_SCRIPT)
    (tmp_path / "cache").mkdir()
    done = subprocess.run([sys.executable, "-W", "error::UserWarning", str(script), str(tmp_path / "cache")],
                          capture_output=True, text=True, timeout=120)  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    first, again = (float(v) for v in done.stdout.split())
    assert again == first == pytest.approx(math.sin(0.5) * 3.0 + 1.0, rel=1e-12)


@pytest.mark.parametrize("command", [["simulate", "--inputs", "table3"], ["identifiability"], ["design"]])
def test_a_network_posterior_option_is_refused_where_nothing_is_sampled(tmp_path, capsys, command):
    """``--nn-posterior`` says how a network is *sampled*: only ``sample`` and ``run`` take
    it.  The other commands with model options had it and ignored it (exit 0)."""
    with pytest.raises(SystemExit) as info:  # an argparse usage error
        main([*command, "--model", "hybrid", "--nn-posterior", "last-layer", "--out", str(tmp_path / "out")])
    assert info.value.code == 2
    assert_one_line_error(capsys.readouterr().err, "unrecognized arguments: --nn-posterior")
    assert not (tmp_path / "out").exists()
