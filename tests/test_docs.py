"""The README and docs/ point only at what exists: every relative link and picture resolves to a
file of the repository, every `#anchor` to a heading of its page (GitHub's anchor rule), and every
picture kept in docs/ is shown somewhere (issue 31: docs that cannot go stale)."""
from __future__ import annotations

import collections
import json
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LINK = re.compile(r"\]\(([^)\s]+)\)")          # [text](target) and ![alt](target)
FENCE = re.compile(r"```.*?```", re.S)          # code blocks: their brackets are code, not links
HEADING = re.compile(r"#{1,6}\s+(.*)")


def _make_docs():
    """tools/make_docs.py as a module (tools/ is not a package)."""
    import importlib.util
    import sys
    if "make_docs" not in sys.modules:          # its dataclass needs the module registered while it loads
        spec = importlib.util.spec_from_file_location("make_docs", ROOT / "tools" / "make_docs.py")
        sys.modules["make_docs"] = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(sys.modules["make_docs"])
    return sys.modules["make_docs"]


def documents(root=ROOT):
    """README.md and docs/*.md: the pages make_docs writes into and these tests read."""
    return _make_docs().pages(root)


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


# ---- what tools/make_docs.py writes: its blocks and its pictures' stamps ------------------------------------------

STAMP = re.compile(r"commit [0-9a-f]{7}, \d{4}-\d{2}-\d{2}")


def test_each_generated_block_names_a_job_carries_its_commit_and_reads_the_same_on_every_page():
    make_docs = _make_docs()
    job_blocks = {block for job, _ in make_docs.JOBS.values() for block in job.blocks}
    seen = {}
    for page in documents():
        for name, (stamp, body) in make_docs.blocks(page.read_text(encoding="utf-8")).items():
            assert name in job_blocks, f"{page.name}: block {name} is no job's"
            assert STAMP.fullmatch(stamp), f"{page.name}: block {name} stamped {stamp!r}, not a commit and a date"
            assert body.strip(), f"{page.name}: block {name} is empty"
            seen.setdefault(name, (page.name, stamp, body))
            assert (stamp, body) == seen[name][1:], f"block {name} differs between {seen[name][0]} and {page.name}"
    assert set(seen) == job_blocks, "a job's block is on no page"


def test_each_generated_picture_carries_the_commit_the_manifest_names():
    make_docs = _make_docs()
    manifest = json.loads((ROOT / "docs" / "generated.json").read_text())
    for name, (job, _) in make_docs.JOBS.items():
        assert name in manifest, f"job {name} has never been run: tools/make_docs.py --only {name}"
        for picture in job.pictures:
            assert make_docs.read_png_stamp(ROOT / "docs" / picture) == manifest[name]["commit"], picture
        for block in job.blocks:
            stamp = next(make_docs.blocks(page.read_text(encoding="utf-8"))[block][0]
                         for page in documents() if block in make_docs.blocks(page.read_text(encoding="utf-8")))
            assert stamp.startswith(f"commit {manifest[name]['commit']}, "), (name, block, stamp)


def test_make_docs_replaces_a_block_on_every_page_and_stamps_a_picture_without_touching_its_pixels(tmp_path):
    import cv2
    import numpy as np
    make_docs = _make_docs()
    (tmp_path / "docs").mkdir()
    opening = "<!-- generated by tools/make_docs.py: figures, commit pending -->\n"
    (tmp_path / "README.md").write_text(f"# Top\n{opening}old\n<!-- end of figures -->\nafter\n")
    (tmp_path / "docs" / "a.md").write_text(f"x\n{opening}<!-- end of figures -->\n")
    (tmp_path / "docs" / "b.md").write_text("no block here\n")
    written = make_docs.write_block("figures", "| a | 1 |\n", "commit abcdef0, 2026-12-07", root=tmp_path)
    assert [p.name for p in written] == ["README.md", "a.md"]
    readme = (tmp_path / "README.md").read_text()
    assert readme == ("# Top\n<!-- generated by tools/make_docs.py: figures, commit abcdef0, 2026-12-07 -->\n"
                      "| a | 1 |\n<!-- end of figures -->\nafter\n")
    assert make_docs.blocks(readme) == {"figures": ("commit abcdef0, 2026-12-07", "| a | 1 |\n")}
    with pytest.raises(make_docs.DocsError, match="no page holds"):
        make_docs.write_block("other", "x\n", "commit abcdef0, 2026-12-07", root=tmp_path)

    picture = tmp_path / "p.png"
    image = np.random.default_rng(0).integers(0, 255, (7, 5, 3), dtype=np.uint8)
    cv2.imwrite(str(picture), image)
    assert make_docs.read_png_stamp(picture) is None
    make_docs.stamp_png(picture, "abcdef0")
    make_docs.stamp_png(picture, "1234567")          # a second stamp replaces the first
    assert make_docs.read_png_stamp(picture) == "1234567"
    assert np.array_equal(cv2.imread(str(picture)), image)
    assert picture.read_bytes().count(b"harp:commit") == 1


def test_make_docs_quick_leaves_out_the_long_jobs_and_names_unknown_ones():
    make_docs = _make_docs()
    quick = make_docs.chosen_jobs(quick=True)
    assert "demo" in quick and all(make_docs.JOBS[n][0].minutes < make_docs.QUICK_MINUTES for n in quick)
    with pytest.raises(make_docs.DocsError, match="no job nonsense"):
        make_docs.chosen_jobs(["nonsense"])
