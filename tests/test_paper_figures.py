"""End to end: ``studies/paper_figures.py`` writes the paper's Figs. 4-6, 9-11 and Tables 1-3.

The script is imported from its path after ``HELI_UQ_STUDY_ROOT`` points at a temporary
directory (``studies/_study.py`` reads it at import), so nothing is written under
``studies/``.
"""

import importlib.util
import json
import pathlib
import sys

import pytest

STUDIES = pathlib.Path(__file__).resolve().parents[1] / "studies"
#: The ODE (x, v) and DAE/momentum (x, p) forms of the model must agree to this (largest
#: absolute difference over angles [rad], rates [rad/s] and momenta [kg m^2/s], tight solves).
ODE_DAE_TOLERANCE = 1e-8
FIGURES = ("paper_fig4_angles.png", "paper_fig5_rates.png", "paper_fig6_momenta.png",
           "paper_fig9_10_record.png", "paper_fig11_table1.png")  # fmt: skip


def _import_script(monkeypatch, root):
    monkeypatch.setenv("HELI_UQ_STUDY_ROOT", str(root))
    monkeypatch.syspath_prepend(str(STUDIES))
    # _study reads HELI_UQ_STUDY_ROOT at import: drop a copy imported earlier (restored after).
    monkeypatch.delitem(sys.modules, "_study", raising=False)
    spec = importlib.util.spec_from_file_location("paper_figures_under_test", STUDIES / "paper_figures.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.slow
def test_paper_figures_script(tmp_path, monkeypatch):
    import heli_uq

    script = _import_script(monkeypatch, tmp_path)
    assert script.FIGURES == tmp_path / "figures"
    assert script.main(["--t1", "5", "--points", "201"]) == 0

    rows = (tmp_path / "results" / "paper_figures.jsonl").read_text(encoding="utf-8").splitlines()
    assert len(rows) == 1
    row = json.loads(rows[0])
    assert row["ode_dae_max_abs_diff"] < ODE_DAE_TOLERANCE
    assert all(d < ODE_DAE_TOLERANCE for d in row["ode_dae_max_abs_diff_by_quantity"].values())
    assert row["loss_v_table1"] > 0.0
    for name in FIGURES:
        path = tmp_path / "figures" / name
        assert path.is_file() and path.stat().st_size > 10_000, name

    text = (tmp_path / "results" / "paper_tables.md").read_text(encoding="utf-8")
    table2 = text.split("## Table 2")[1].split("## Table 1")[0]
    names = [p.name for p in heli_uq.HeliModel().parameters()]
    rows2 = [line for line in table2.splitlines() if line.startswith("| `")]
    assert [line.split("`")[1] for line in rows2] == names  # one row per base parameter, in order
    table1 = text.split("## Table 1")[1].split("## Table 3")[0]
    assert all(f"| `{n}` |" in table1 for n in names)
    assert "## Table 3" in text
