"""The README is a short front door and every relative link in it and in docs/ leads somewhere."""

import re
from pathlib import Path
from urllib.parse import unquote

import pytest

ROOT = Path(__file__).resolve().parents[2]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
#: The lines .ci/run and the users copy; they must stay exactly as they are.
DEMO = 'Demo: `python3.11 -m venv .venv && .venv/bin/pip install -e ".[blender,test]" && .venv/bin/python -m facecap demo`'
TESTS = 'Tests: `python3.11 -m venv .venv && .venv/bin/pip install -e ".[blender,test]" && .venv/bin/python -m pytest`'

LINK = re.compile(r"!?\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
FENCE = re.compile(r"^```.*?^```", re.S | re.M)
CODE = re.compile(r"`[^`\n]*`")


def links(page):
    """Link and image targets of a Markdown page, outside code blocks and code spans."""
    text = CODE.sub("", FENCE.sub("", page.read_text(encoding="utf-8")))
    return LINK.findall(text)


def test_there_are_docs_pages():
    names = {p.name for p in PAGES}
    assert {"README.md", "architecture.md", "strategies.md", "performance.md"} <= names


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_relative_links_point_to_files(page):
    found = links(page)
    broken = []
    for target in found:
        if re.match(r"^[a-z][a-z0-9+.-]*:", target, re.I) or target.startswith("#"):
            continue  # http(s), mailto: not checked here; same-page anchors
        path = (page.parent / unquote(target.split("#", 1)[0])).resolve()
        if not path.exists():
            broken.append(target)
        assert path.is_relative_to(ROOT), f"{page.name}: {target} leaves the repository"
    assert not broken, f"{page.relative_to(ROOT)}: broken links {broken}"


def test_link_finder_sees_links_and_skips_code(tmp_path):
    page = tmp_path / "p.md"
    page.write_text("[a](x.md) ![b](img/y.png \"t\") `[c](no.md)`\n```\n[d](no2.md)\n```\n[e](z.md#part)\n")
    assert links(page) == ["x.md", "img/y.png", "z.md#part"]


def test_readme_is_a_front_door():
    lines = (ROOT / "README.md").read_text(encoding="utf-8").splitlines()
    assert len(lines) <= 160, f"README.md has {len(lines)} lines; the detail belongs in docs/"
    assert lines.count(DEMO) == 1 and lines.count(TESTS) == 1
    # .ci/run runs the one line matching ^Tests: `...`$
    assert [line for line in lines if re.fullmatch(r"Tests: `.*`", line)] == [TESTS]
    assert any(re.search(r"!\[[^\]]+\]\(docs/images/[^)]+\.png\)", line) for line in lines)  # one picture


def test_doc_images_are_small_pngs_and_used():
    images = sorted((ROOT / "docs" / "images").glob("*.png"))
    assert images
    used = {(page.parent / t).resolve() for page in PAGES for t in links(page)}
    for image in images:
        assert image.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", image.name
        assert image.stat().st_size < 150 * 1024, f"{image.name}: {image.stat().st_size} bytes"
        assert image.resolve() in used, f"{image.name} is not shown on any page"
