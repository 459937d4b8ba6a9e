"""The tree works from any clone: no absolute path of a development machine in code, tests or docs (the
shared data is found beside the checkout, ``tests/shared_data.py``), and the user docs read as docs, not
as a development log."""

import re
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
SKIP_DIRS = {".git", ".venv", "__pycache__", "facecap.egg-info", ".pytest_cache", ".ruff_cache"}
TEXT_SUFFIXES = {".py", ".md", ".toml", ".txt", ".json", ".cfg", ".ini", ".yml", ".yaml", ".js", ".css", ".html",
                 ".csv", ".sh", ""}
#: Roots of home and work folders on Linux, macOS and Windows (written so this file does not match itself).
MACHINE_PATH = re.compile(r"(?<![\w.~-])(?:/(?:" + "|".join(["work", "home", "Users", "root", "mnt"]) + r")/[\w.-]"
                          r"|[A-Z]:\\(?:" + "|".join(["Users", "work"]) + r")\\)")
#: Words of a development log that a user reading the docs has no use for.
LOG_WORDS = re.compile(r"\bissue \d+|\bthis branch\b|\bbefore this change\b|\bafter this change\b|\bthis PR\b", re.I)
USER_DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")), ROOT / "sample_blends" / "README.md"]


def _ignored():
    """Files git ignores (a demo's or a test's outputs, which name where they were written): not the tree's."""
    try:
        out = subprocess.run(["git", "ls-files", "--others", "--ignored", "--exclude-standard"], cwd=ROOT,
                             capture_output=True, text=True, timeout=60)
    except OSError:
        return set()
    return {ROOT / line for line in out.stdout.splitlines()} if out.returncode == 0 else set()


def tree_files():
    """Every text file of the checkout (what a clone holds, plus untracked work in progress; not what git ignores)."""
    ignored = _ignored()
    for path in sorted(ROOT.rglob("*")):
        rel = path.relative_to(ROOT)
        # .venv-3.13 and the like: a second Python's environment (CI makes one for the core tests)
        if any(part in SKIP_DIRS or part.startswith(".venv") for part in rel.parts) or not path.is_file() \
                or path in ignored:
            continue
        if path.suffix.lower() in TEXT_SUFFIXES and path.stat().st_size < 5_000_000:
            yield path


def machine_paths(text):
    return [m.group(0) for m in MACHINE_PATH.finditer(text)]


def test_the_pattern_finds_machine_paths_and_not_ordinary_ones():
    home = "/" + "home/ana/take.c3d"
    found = machine_paths(f'markers = "{home}"; see /{"work"}/shared/x and C:\\{"Users"}\\ana\\t.csv')
    assert found == [home[:7], f'/{"work"}/s', f'C:\\{"Users"}\\']
    assert not machine_paths("../shared/data, ~/takes/a.c3d, out/work/x, docs/home/index, /tmp/x, s/root/y")


def test_no_absolute_machine_path_in_the_tree():
    hits = []
    for path in tree_files():
        try:
            text = path.read_text(encoding="utf-8")
        except UnicodeDecodeError:
            continue
        for number, line in enumerate(text.splitlines(), start=1):
            if machine_paths(line):
                hits.append(f"{path.relative_to(ROOT)}:{number}: {line.strip()[:100]}")
    assert not hits, "absolute machine paths (use a path relative to the checkout or tests/shared_data.py):\n" + \
        "\n".join(hits)


@pytest.mark.parametrize("page", USER_DOCS, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_docs_carry_no_development_log_words(page):
    hits = [f"line {n}: {line.strip()[:100]}" for n, line in enumerate(page.read_text(encoding="utf-8").splitlines(), 1)
            if LOG_WORDS.search(line)]
    assert not hits, f"{page.relative_to(ROOT)} reads like a development log:\n" + "\n".join(hits)


def test_docs_index_lists_every_page():
    index = (ROOT / "docs" / "README.md").read_text(encoding="utf-8")
    missing = [p.name for p in sorted((ROOT / "docs").glob("*.md")) if p.name != "README.md" and f"({p.name})" not in index]
    assert not missing, f"docs/README.md does not link {missing}"
