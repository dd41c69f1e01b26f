"""Every relative link in the repository's markdown resolves: the file exists and, for a
``#anchor``, the target holds a heading with that GitHub slug or an ``<a id>``.  The README
links into ``studies/notes/`` and back; a heading renamed or a note moved breaks a link
silently on GitHub, so it fails here."""

import pathlib
import re

REPO = pathlib.Path(__file__).resolve().parents[1]
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")
FENCE = re.compile(r"```.*?```", re.S)


def github_slugs(text: str) -> set[str]:
    """The anchors GitHub makes for a markdown text: each heading lower-cased, punctuation
    other than ``-`` and ``_`` dropped, spaces as ``-``, a repeated heading suffixed
    ``-1``, ``-2``; plus explicit ``<a id="...">`` anchors."""
    anchors = set(re.findall(r'<a id="([^"]+)"', text))
    seen: dict[str, int] = {}
    for line in FENCE.sub("", text).splitlines():
        heading = re.match(r"#{1,6}\s+(.*)", line)
        if heading:
            slug = re.sub(r"[^\w\- ]", "", heading.group(1).strip().lower()).replace(" ", "-")
            count = seen.get(slug, 0)
            seen[slug] = count + 1
            anchors.add(slug if count == 0 else f"{slug}-{count}")
    return anchors


def broken_links(path: pathlib.Path) -> list[str]:
    broken = []
    for match in LINK.finditer(FENCE.sub("", path.read_text())):
        target = match.group(1)
        if re.match(r"[a-z]+:", target):  # http(s), mailto: not checked offline
            continue
        file, _, anchor = target.partition("#")
        dest = (path.parent / file).resolve() if file else path
        if not dest.exists():
            broken.append(f"{target}: no such file")
        elif anchor and dest.suffix == ".md" and anchor not in github_slugs(dest.read_text()):
            broken.append(f"{target}: no heading or anchor '{anchor}' in {dest.name}")
    return broken


def markdown_files() -> list[pathlib.Path]:
    files = [REPO / "README.md", REPO / "tests" / "README.md", REPO / "data" / "README.md"]
    return files + sorted((REPO / "studies").rglob("*.md"))


def test_slugs_follow_github():
    text = "# Results (paper vs heli_uq, from the stored studies)\n## Tests and CI\n## Tests and CI\n"
    assert github_slugs(text) == {"results-paper-vs-heli_uq-from-the-stored-studies",
                                  "tests-and-ci", "tests-and-ci-1"}


def test_every_relative_link_and_anchor_resolves(tmp_path):
    bad = tmp_path / "bad.md"
    bad.write_text("# Title\n[ok](#title) [gone](#nowhere) [file](missing.md)\n")
    assert len(broken_links(bad)) == 2  # the checker finds what it must
    problems = {str(f.relative_to(REPO)): broken_links(f) for f in markdown_files()}
    assert {f: p for f, p in problems.items() if p} == {}
