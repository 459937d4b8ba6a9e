"""The README is a short front door and every relative link in it and in docs/ leads somewhere."""

import re
from pathlib import Path
from urllib.parse import unquote

import pytest

ROOT = Path(__file__).resolve().parents[2]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
#: The lines .ci/run and the users copy; they must stay exactly as they are. Each first picks a Python that
#: has a bpy wheel (3.13 or 3.11), whichever this machine has.
PICK = ("py=$(for p in python3.13 python3.11 python3; do $p -c 'import sys; assert sys.version_info[:2] in "
        "[(3, 13), (3, 11)]; print(sys.executable)' 2>/dev/null && break; done); ${py:?needs Python 3.13 or 3.11}")
DEMO = f'Demo: `{PICK} -m venv .venv && .venv/bin/pip install -e ".[blender,test]" && .venv/bin/python -m facecap demo`'
TESTS = f'Tests: `{PICK} -m venv .venv && .venv/bin/pip install -e ".[blender,test]" && .venv/bin/python -m pytest`'

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


def _pick(tmp_path, **programs):
    """Run the README's Python pick with only ``programs`` (name -> shell script body) on PATH."""
    import subprocess

    for name, body in programs.items():
        path = tmp_path / name
        path.write_text(f"#!/bin/sh\n{body}\n")
        path.chmod(0o755)
    return subprocess.run(["/bin/sh", "-c", f'{PICK} -c "import sys; print(sys.version_info[:2])"'],
                          env={"PATH": str(tmp_path)}, capture_output=True, text=True, timeout=120)


def test_the_readme_commands_pick_whichever_python_the_machine_has(tmp_path):
    """A machine with only one of 3.13 and 3.11, under any of the three names; a pyenv shim of a version
    that is not selected (it exits 127) is passed over; no suitable Python is a one-line reason."""
    import sys

    real = f'exec "{sys.executable}" "$@"'
    wanted = f"({sys.version_info[0]}, {sys.version_info[1]})"
    shim = 'echo "pyenv: python3.13: command not found" >&2; exit 127'
    got = _pick(tmp_path, **{"python3.13": shim, "python3": real})
    assert got.returncode == 0 and got.stdout.strip() == wanted, got.stderr
    old = tmp_path / "old"
    old.mkdir()
    # a Python without a bpy wheel (3.12, say) fails the check as Python does: a traceback on stderr
    got = _pick(old, python3='echo "AssertionError" >&2; exit 1')
    assert got.returncode != 0 and "py: needs Python 3.13 or 3.11" in got.stderr


def test_doc_images_are_small_pngs_and_used():
    images = sorted((ROOT / "docs" / "images").glob("*.png"))
    assert images
    used = {(page.parent / t).resolve() for page in PAGES for t in links(page)}
    for image in images:
        assert image.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", image.name
        assert image.stat().st_size < 150 * 1024, f"{image.name}: {image.stat().st_size} bytes"
        assert image.resolve() in used, f"{image.name} is not shown on any page"
