"""The README's results table is generated from the stored study results: the block in
README.md must be exactly what ``python -m studies table`` writes now."""

import importlib.util
import pathlib

_PATH = pathlib.Path(__file__).resolve().parents[1] / "studies" / "results_table.py"
_spec = importlib.util.spec_from_file_location("results_table", _PATH)
results_table = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(results_table)


def test_the_readme_table_is_generated_from_the_stored_results():
    block = results_table.readme_block()
    assert block is not None, "README.md has no results-table markers"
    assert block == results_table.results_table(), "stale: run python -m studies table"


def test_a_missing_result_says_not_run(monkeypatch, tmp_path):
    monkeypatch.setattr(results_table, "RESULTS", tmp_path)
    table = results_table.results_table()
    missing = [line for line in table.splitlines() if "| not run |" in line]
    stored = [name for _, name in results_table.POSTERIOR_ROWS]
    stored += ["hybrid_rig.jsonl", "discover_rig/discovery.json"]
    assert len(missing) == len(stored)
    for name in stored:
        assert sum(f"`{name}`" in line for line in missing) == 1, name
