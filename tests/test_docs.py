"""The README and docs/ point only at what exists: every relative link and picture resolves to a
file of the repository, every `#anchor` to a heading of its page (GitHub's anchor rule), and every
picture kept in docs/ is shown somewhere (issue 31: docs that cannot go stale)."""
from __future__ import annotations

import collections
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LINK = re.compile(r"\]\(([^)\s]+)\)")          # [text](target) and ![alt](target)
FENCE = re.compile(r"```.*?```", re.S)          # code blocks: their brackets are code, not links
HEADING = re.compile(r"#{1,6}\s+(.*)")


def documents(root=ROOT):
    return [root / "README.md"] + sorted((root / "docs").glob("*.md"))


def heading_anchor(text):
    """GitHub's anchor of a heading: lower case, punctuation dropped (word characters, hyphens and
    spaces kept), spaces turned to hyphens."""
    return re.sub(r"[^\w\- ]", "", text.strip().lower()).replace(" ", "-")


def anchors(page):
    """The anchors of a markdown page's headings; a repeated heading's get -1, -2, ... as on GitHub."""
    counts, found = collections.Counter(), set()
    for line in FENCE.sub("", page.read_text(encoding="utf-8")).splitlines():
        match = HEADING.match(line)
        if match:
            anchor = heading_anchor(match.group(1))
            found.add(anchor if not counts[anchor] else f"{anchor}-{counts[anchor]}")
            counts[anchor] += 1
    return found


def broken_links(pages):
    """(page, target, why) for each relative link of `pages` that points at nothing."""
    broken = []
    for page in pages:
        for target in LINK.findall(FENCE.sub("", page.read_text(encoding="utf-8"))):
            if re.match(r"[a-z]+:", target):           # http(s):, mailto: ...
                continue
            path, _, anchor = target.partition("#")
            resolved = (page.parent / path).resolve() if path else page.resolve()
            if not resolved.exists():
                broken.append((page.name, target, "no such file"))
            elif anchor and resolved.suffix == ".md" and anchor not in anchors(resolved):
                broken.append((page.name, target, "no such heading"))
    return broken


def unshown_pictures(pages, folder):
    """Pictures in `folder` that no page shows or links."""
    text = "".join(page.read_text(encoding="utf-8") for page in pages)
    return sorted(picture.name for picture in folder.glob("*.png") if picture.name not in text)


def test_every_link_and_picture_in_the_readme_and_docs_resolves():
    assert broken_links(documents()) == []


def test_every_picture_in_docs_is_shown():
    assert unshown_pictures(documents(), ROOT / "docs") == []


def test_the_check_finds_a_missing_picture_a_missing_heading_and_an_unshown_picture(tmp_path):
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "shown.png").write_bytes(b"")
    (tmp_path / "docs" / "forgotten.png").write_bytes(b"")
    (tmp_path / "docs" / "page.md").write_text("# A page\n## The `full` preset, again (issue 34)\n\n"
                                               "```\n# not a heading\n[not](a_link.md)\n```\n")
    (tmp_path / "README.md").write_text(
        "![ok](docs/shown.png) ![gone](docs/gone.png) [ok](docs/page.md#the-full-preset-again-issue-34) "
        "[bad](docs/page.md#not-a-heading) [web](https://example.org/x.png) [self](#missing)\n")
    assert broken_links(documents(tmp_path)) == [("README.md", "docs/gone.png", "no such file"),
                                                 ("README.md", "docs/page.md#not-a-heading", "no such heading"),
                                                 ("README.md", "#missing", "no such heading")]
    assert unshown_pictures(documents(tmp_path), tmp_path / "docs") == ["forgotten.png"]
