"""The notebooks: every ``notebooks/NAME.py`` has its executed ``NAME.ipynb`` beside it with
the same code and with outputs (so it reads on GitHub and cannot silently go stale), and
each executes at the small size (``study`` mark: ``python -m pytest -m study``, outside
the README's test command).  The discovery notebook must name the effect
it hides."""

import importlib.util
import json
import pathlib

import jupytext
import nbformat
import pytest

NOTEBOOKS_DIR = pathlib.Path(__file__).resolve().parents[1] / "notebooks"
_spec = importlib.util.spec_from_file_location("notebook_execute", NOTEBOOKS_DIR / "execute.py")
execute_module = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(execute_module)
NAMES = execute_module.NOTEBOOKS
#: Seconds one cell of a small notebook may take before the run counts as hung.
CELL_TIMEOUT_S = 900


def _code(nb):
    return [c.source.strip() for c in nb.cells if c.cell_type == "code"]


def test_the_list_of_notebooks_is_the_folder():
    sources = [p.stem for p in NOTEBOOKS_DIR.glob("*.py") if not p.stem.startswith(("_", "execute"))]
    assert sorted(NAMES) == sorted(sources)


@pytest.mark.parametrize("name", NAMES)
def test_the_stored_notebook_is_the_executed_script(name):
    script = jupytext.read(NOTEBOOKS_DIR / f"{name}.py")
    stored = nbformat.read(NOTEBOOKS_DIR / f"{name}.ipynb", as_version=4)
    assert _code(stored) == _code(script), f"{name}.ipynb is stale: run python notebooks/execute.py {name}"
    outputs = [o for c in stored.cells if c.cell_type == "code" for o in c.outputs]
    assert outputs, f"{name}.ipynb has no outputs"
    assert not [o for o in outputs if o.output_type == "error"]


@pytest.mark.slow
@pytest.mark.study
@pytest.mark.parametrize("name", NAMES)
def test_the_notebook_executes_at_the_small_size(name, tmp_path):
    nb = execute_module.execute(name, "small", out=tmp_path / f"{name}.ipynb", timeout=CELL_TIMEOUT_S,
                                workdir=tmp_path)
    assert all(c.execution_count for c in nb.cells if c.cell_type == "code")
    if name == "discovery":
        found = json.loads((tmp_path / "out" / "discovery" / "discovery.json").read_text())
        assert (found["effect"], found["axis"]) == ("torque_offset", "yaw")
