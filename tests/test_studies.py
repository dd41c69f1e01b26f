"""Every study of the registry (``python -m studies``) runs at its smallest size (slow set):
each command exits 0 and writes into the output root it is given, never into the stored
``studies/results/``.  These runs carry the ``study`` mark: they are outside the README's
test command (CI), ``python -m pytest -m study`` runs them.  The notebooks are executed by
``tests/test_notebooks.py``."""

import json
import math
import os
import pathlib
import sys

import numpy as np
import pytest

REPO = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
from studies.__main__ import STUDIES, main, run  # noqa: E402

REAL_FILE = (pathlib.Path(os.environ.get("HELI_UQ_DATA", "/nonexistent"))
             / "Lab-Helicopter_Experimental-data.csv")
#: Studies executed elsewhere in the tests.
ELSEWHERE = ("notebooks",)


def test_the_registry_names_every_study_script():
    """A new study script must be registered (so ``run --size quick`` and the tests see it)."""
    scripts = {p.stem for p in (REPO / "studies").glob("*.py") if not p.stem.startswith("_")}
    scripts -= {"results_table"}
    commands = " ".join(str(a) for s in STUDIES for cmd in s.quick + s.paper for a in cmd)
    assert not [s for s in scripts if f"{s}.py" not in commands]


def test_unknown_study_is_refused_in_one_line(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["run", "--only", "no_such_study"])
    assert exc.value.code == 2 and "unknown study no_such_study" in capsys.readouterr().err


@pytest.mark.slow
@pytest.mark.study
@pytest.mark.parametrize("study", [s for s in STUDIES if s.name not in ELSEWHERE], ids=lambda s: s.name)
def test_the_study_runs_at_its_quick_size(study, tmp_path):
    if study.needs_record and not REAL_FILE.is_file():
        pytest.skip("the rig record is not available (set HELI_UQ_DATA)")
    kept = [REPO / "studies" / "results", REPO / "studies" / "figures"]
    stored = {p: p.stat().st_mtime for d in kept for p in d.rglob("*") if p.is_file()}
    assert run("quick", [study.name], root=tmp_path) == 0
    text = (tmp_path / "results" / "studies_quick.jsonl").read_text()
    rows = [json.loads(line) for line in text.splitlines()]
    assert [(r["study"], r["status"]) for r in rows] == [(study.name, 0)]
    written = [p for p in tmp_path.rglob("*") if p.is_file() and p.name != "studies_quick.jsonl"]
    assert written, "the study wrote nothing under its output root"
    after = {p: p.stat().st_mtime for d in kept for p in d.rglob("*") if p.is_file()}
    assert after == stored, "a quick run changed the stored results or figures"


def test_a_jittered_base_keeps_the_pitch_statics_of_the_rig_fit():
    """The confusion study's other fit of the rig (``--base-jitter``): spread around the
    rig fit, reproducible from the seed, ``g`` and the pitch statics
    ``K_theta_theta / (m r_c)`` kept (else a 5 % spread turns the pitch over)."""
    from heli_uq.model import RIG_FIT
    from studies.discovery_confusion import jittered_base

    assert jittered_base(3, 0.0) == RIG_FIT
    base = jittered_base(3, 0.1)
    assert base == jittered_base(3, 0.1) and base != jittered_base(4, 0.1)
    assert base["g"] == RIG_FIT["g"]
    ratio = {k: base[k] / RIG_FIT[k] for k in RIG_FIT}
    assert ratio["K_theta_theta"] == pytest.approx(ratio["m"] * ratio["r_c"], rel=1e-12)
    moved = [k for k in RIG_FIT if abs(math.log(ratio[k])) > 1e-3]
    assert len(moved) >= len(RIG_FIT) - 2, moved


def test_a_hidden_friction_can_follow_another_smoothing_than_the_fitted_one():
    """``--hidden-omega-s``: the record's friction law is ``tanh(omega / W)`` with the given
    width (another simulator's law), everything else as with the fitted term's width; the
    rest of the case (other effects, the truth) is unchanged."""
    from heli_uq.model.terms.coulomb_friction import OMEGA_S
    from heli_uq.simulation.synthetic import ENCODER_QUANTUM
    from studies.discovery_confusion import make_record

    case = "yaw:coulomb_friction+pitch:torque_offset"
    sharp, truth, model = make_record(case, "rig_steps", 3, 8.0, omega_s=OMEGA_S / 10)
    plain, truth_plain, model_plain = make_record(case, "rig_steps", 3, 8.0)
    assert [(t.kind, getattr(t, "omega_s", None)) for t in model.effects] == [
        ("coulomb_friction", OMEGA_S / 10), ("torque_offset", None)]
    assert model_plain.effects[0].omega_s == OMEGA_S and truth == truth_plain
    assert np.array_equal(sharp.u, plain.u)
    # same noise draws: the sharper law (less creep where the yaw sticks) moves the yaw by
    # more than one encoder count within 8 s (measured: two counts)
    assert np.max(np.abs(sharp.y[:, 1] - plain.y[:, 1])) > ENCODER_QUANTUM


def test_a_hidden_tilt_is_a_case_outside_the_table_and_fix_parses():
    """``--cases yaw:thrust_tilt`` hides the derived ``cos theta`` at ``a = 1`` (outside the
    effects table, never a default case); it weakens the yaw torques where the pitch is off
    level, so the yaw leaves the null record's (same inputs and noise) by many encoder
    counts within 8 s.  ``--fix NAME=VALUE`` parses to the pair discover's priors take."""
    import argparse

    from heli_uq.simulation.synthetic import ENCODER_QUANTUM
    from studies.discovery_confusion import EXTRA_CASES, _fixed, make_record

    assert "yaw:thrust_tilt" in EXTRA_CASES
    tilted, truth, model = make_record("yaw:thrust_tilt", "rig_steps", 3, 8.0)
    plain, truth_plain, _ = make_record("none", "rig_steps", 3, 8.0)
    assert [t.kind for t in model.effects] == ["thrust_tilt"] and truth["a_yaw"] == 1.0
    assert {k: v for k, v in truth.items() if k != "a_yaw"} == truth_plain
    assert np.array_equal(tilted.u, plain.u)
    assert np.max(np.abs(tilted.y[:, 1] - plain.y[:, 1])) > 10 * ENCODER_QUANTUM
    assert _fixed("a_yaw=1") == ("a_yaw", 1.0)
    for bad in ("a_yaw", "a_yaw=uniform:0:1"):  # no value; a prior, not a fixed value
        with pytest.raises(argparse.ArgumentTypeError, match="NAME=VALUE"):
            _fixed(bad)


def test_the_confusion_study_checks_the_identified_ratio_of_a_torque():
    """A friction level's interval in N m holds the truth as far as the common scale's prior
    does; the study also checks its ratio to the axis' inertia, the quantity the record
    identifies: at theta_ref = 0, ``M22 = J_bc + m r_c^2 + J_s``; pitch: ``M11 = J_bc +
    m (r_c^2 + h^2)``."""
    from studies.discovery_confusion import ratio_coverage

    truth = {"J_bc": 0.01, "m": 1.0, "r_c": 0.1, "h": 0.02, "J_s": 0.005, "F_c_yaw": 0.025,
             "F_c_pitch": 0.003}  # fmt: skip
    m22, m11 = 0.01 + 0.01 + 0.005, 0.01 + (0.01 + 0.0004)
    found = {"ci95": [1e-4, 1.0], "per_inertia": {"ci95": [0.999 * 0.025 / m22, 1.001 * 0.025 / m22],
                                                  "theta_ref": 0.0}}
    got = ratio_coverage(found, truth, "F_c_yaw", "yaw")
    assert got["ratio_covered"] and np.isclose(got["ratio_truth"], 0.025 / m22, rtol=1e-12)
    found["per_inertia"]["ci95"] = [1.01 * 0.025 / m22, 1.1 * 0.025 / m22]  # misses the truth
    assert not ratio_coverage(found, truth, "F_c_yaw", "yaw")["ratio_covered"]
    pitch = {"ci95": [0, 1], "per_inertia": {"ci95": [0.0, 1.0]}}
    assert np.isclose(ratio_coverage(pitch, truth, "F_c_pitch", "pitch")["ratio_truth"], 0.003 / m11,
                      rtol=1e-12)  # fmt: skip
    assert ratio_coverage({"ci95": [0.2, 0.4]}, truth, "delta_yaw", "yaw") == {}  # not a torque


def _confusion_rows() -> list[dict]:
    rows = []
    for path in sorted((REPO / "studies" / "results").glob("discovery_confusion*.jsonl")):
        for line in path.read_text().splitlines():
            row = json.loads(line)
            if (row.get("best") or {}).get("score_per_sample") is not None:
                rows.append(row)
    return rows


def test_the_log_density_margin_lies_between_the_stored_null_and_effect_records():
    """The margin of ``none`` is calibrated on the confusion study's records: every record
    without a hidden effect scored below it, every record whose hidden effect was named
    as hidden scored above it.  A margin moved outside that range, or a stored record that
    contradicts it, fails here."""
    from heli_uq.discovery import MARGIN_PER_SAMPLE

    rows = _confusion_rows()
    nulls = [r["best"]["score_per_sample"] for r in rows if r["case"] == "none"]
    named = [r["best"]["score_per_sample"] for r in rows
             if r["case"] != "none" and r["correct"] and "+" not in r["case"]]  # fmt: skip
    assert len(nulls) >= 30 and len(named) >= 100
    assert max(nulls) < MARGIN_PER_SAMPLE < min(named)
