"""The package layout: one folder per stage, imports one way (data -> model -> simulation ->
probability -> inference -> identifiability -> output -> discovery -> cli), curated ``__all__``."""

import ast
import importlib
import pathlib

import pytest

PACKAGE = pathlib.Path(__file__).resolve().parents[1] / "heli_uq"
#: Layer of each top-level part of the package; a module may import only from its own layer
#: or lower ones.  ``heli_uq/__init__.py`` (the curated facade) is exempt.
LAYERS = {
    "_jax_config": 0, "errors": 0, "io": 0, "figure": 0, "log": 0, "provenance": 0,
    "data": 1, "model": 2, "simulation": 3, "probability": 4, "inference": 5,
    "identifiability": 6, "output": 7, "discovery": 8, "design": 8, "calibration": 8, "cli": 9, "executor": 0,
}  # fmt: skip


def _part(module: str) -> str:
    """``heli_uq.model.terms.base`` -> ``model``."""
    return module.split(".")[1]


def _imports(path: pathlib.Path):
    """Every ``heli_uq`` module imported anywhere in the file (also inside functions)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.startswith("heli_uq."):
                    yield node.lineno, alias.name
        elif isinstance(node, ast.ImportFrom) and node.module:
            if node.module == "heli_uq":
                for alias in node.names:
                    yield node.lineno, f"heli_uq.{alias.name}"
            elif node.module.startswith("heli_uq."):
                yield node.lineno, node.module


def _modules():
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(PACKAGE.parent).with_suffix("")
        name = ".".join(rel.parts)
        if name != "heli_uq.__init__":
            yield name, path


def test_every_part_has_a_layer():
    parts = {_part(name) for name, _ in _modules()}
    assert parts <= set(LAYERS), parts - set(LAYERS)


def test_imports_go_one_way():
    upward = []
    for name, path in _modules():
        layer = LAYERS[_part(name)]
        for line, target in _imports(path):
            if LAYERS[_part(target)] > layer:
                upward.append(f"{path.relative_to(PACKAGE.parent)}:{line} imports {target}")
    assert not upward, "imports against the data flow:\n" + "\n".join(upward)


def test_the_check_catches_an_upward_import(tmp_path):
    """The walker sees imports inside functions too (a check that cannot fail is no check)."""
    bad = tmp_path / "bad.py"
    bad.write_text("def f():\n    from heli_uq.output.plots import plot_bands\n")
    assert [t for _, t in _imports(bad)] == ["heli_uq.output.plots"]


@pytest.mark.parametrize("package", ["heli_uq", "heli_uq.data", "heli_uq.model", "heli_uq.simulation",
                                     "heli_uq.probability", "heli_uq.inference",
                                     "heli_uq.identifiability", "heli_uq.output",
                                     "heli_uq.discovery", "heli_uq.calibration"])  # fmt: skip
def test_curated_api(package):
    module = importlib.import_module(package)
    missing = [n for n in module.__all__ if not hasattr(module, n)]
    assert not missing, missing
    assert len(set(module.__all__)) == len(module.__all__)


def test_no_exported_name_shadows_a_subpackage():
    """``import heli_uq.<stage>.<module> as m`` must reach the module: a function exported
    under a subpackage's name (``heli_uq.simulate`` once was both) breaks that import."""
    import types

    import heli_uq

    for sub in sorted(p.name for p in PACKAGE.iterdir() if (p / "__init__.py").exists()):
        importlib.import_module(f"heli_uq.{sub}")
        assert isinstance(getattr(heli_uq, sub), types.ModuleType), sub


def _string_constants(path):
    """String constants of a module that are neither docstrings nor parts of f-strings."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    skip = set()
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        if isinstance(body, list) and body and isinstance(body[0], ast.Expr):
            skip.add(id(body[0].value))
        if isinstance(node, ast.JoinedStr):
            skip.update(id(n) for n in ast.walk(node))
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in skip:
            yield node.lineno, node.value


def test_only_the_mechanics_declaration_names_table2():
    """Only the mechanics (with its Lagrangian) and the paper's linear torque name the
    Table 2 parameters; every later stage iterates over the model's declarations."""
    from heli_uq.model import TABLE2

    names = set(TABLE2) - {"g"}
    allowed = {"model/terms/rigid_body.py", "model/terms/linear_torque.py", "model/lagrangian.py"}
    offenders = [f"{path.relative_to(PACKAGE)}:{line} {text!r}"
                 for path in PACKAGE.rglob("*.py") if str(path.relative_to(PACKAGE)) not in allowed
                 for line, text in _string_constants(path) if text in names]  # fmt: skip
    assert not offenders, offenders


def test_library_code_does_not_print():
    """Progress goes through logging (heli_uq.log); only the CLI writes to stdout itself."""
    found = []
    for name, path in _modules():
        if _part(name) == "cli":
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            where = f"{path.relative_to(PACKAGE.parent)}:{getattr(node, 'lineno', '?')}"
            if isinstance(node, ast.Call) and getattr(node.func, "id", None) == "print":
                found.append(where)
            elif isinstance(node, ast.Name) and node.id == "print":
                found.append(where + " (print passed as a callback)")
    assert not found, found
