"""CI runs the README's test command: the ``pytest`` invocation in the README's set-up block
is the one ``.ci/run`` executes (a drift between the two would make CI check another suite
than the one users are told to run)."""

import pathlib
import re

import pytest

REPO = pathlib.Path(__file__).resolve().parents[1]
PYTEST = re.compile(r"python -m pytest[^\n`&|;]*")


def _commands(text: str) -> list[str]:
    return [" ".join(m.group(0).split()) for m in PYTEST.finditer(text)]


def test_ci_runs_the_readme_test_command():
    readme = (REPO / "README.md").read_text()
    block = re.search(r"```bash\n(python3 -m pip install -e \"\.\[test\]\" && python -m pytest[^\n]*)\n```",
                      readme)  # fmt: skip
    assert block is not None, "README.md has no set-up block with the test command"
    lines = (REPO / ".ci" / "run").read_text().splitlines()
    ci = [line for line in lines if not line.lstrip().startswith("#")]
    assert _commands(block.group(1)) == _commands("\n".join(ci))


@pytest.mark.xdist_group("ci_guard")
def test_loadgroup_sends_a_group_to_one_worker(request):
    """``--dist loadgroup`` groups by a suffix pytest-xdist adds to the node id; pytest 9.2
    ignores it (pytest-xdist issue 1386), and every worker then computes the shared NUTS
    and emcee fixtures again (their setup twice in one run; on 2 cores the wall time
    barely changed, the copies ran side by side)."""
    if not getattr(request.config.option, "loadgroup", False):
        pytest.skip("not run by pytest-xdist with --dist loadgroup")
    assert request.node.nodeid.endswith("@ci_guard")
