# SPDX-License-Identifier: GPL-3.0-or-later
"""Every Blender release the ``bpy`` wheels offer is served by an extension build or excluded on purpose.

Blender publishes each release as a ``bpy`` wheel on PyPI, tagged with its Python and platform. This asks
pip which releases exist (``pip index versions bpy`` per Python and platform) and fails for any that no
build in ``solvers/extension_builds.py`` installs into with matching wheels (same Python, a zip for that
platform) and that ``EXCLUDED`` does not name: a new Blender on a new Python, a platform Blender took up
again, a gap between two builds' ranges. It also fails when docs/install.md's table has no row for a
release, so the table users read stays complete.
"""

import re
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from matrix_env import MATRIX, missing_prerequisite

from facecap.solvers.extension_builds import BUILDS, EXCLUDED, version_tuple

pytestmark = pytest.mark.slow

DOCS = Path(__file__).resolve().parents[2] / "docs" / "install.md"
#: Blender platform -> the wheel platform tags a bpy wheel for it may carry (pip matches them exactly).
PIP_PLATFORMS = {
    "linux-x64": [f"manylinux_2_{n}_x86_64" for n in (17, 24, 27, 28, 31, 34, 35, 36, 38, 39, 40)],
    "linux-arm64": [f"manylinux_2_{n}_aarch64" for n in (17, 24, 27, 28, 31, 34, 35, 36, 38, 39, 40)],
    "windows-x64": ["win_amd64"],
    "windows-arm64": ["win_arm64"],
    "macos-arm64": ["macosx_30_0_arm64"],  # pip expands a macOS tag to every older macOS
    "macos-x64": ["macosx_30_0_x86_64"],
}
#: Pythons looked at on linux-x64, where every Blender release has a wheel: a Blender moving to a Python
#: no build is for shows up here; the other platforms are looked at for the builds' Pythons.
SCANNED_PYTHONS = ("3.10", "3.11", "3.12", "3.13", "3.14", "3.15")


def _offered(platform, python):
    """The bpy versions pip finds for one Blender platform and Python (empty when there are none)."""
    cmd = [sys.executable, "-m", "pip", "index", "versions", "bpy", "--only-binary=:all:", "--python-version",
           python, "--implementation", "cp", "--disable-pip-version-check"]
    for tag in PIP_PLATFORMS[platform]:
        cmd += ["--platform", tag]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    found = re.search(r"^Available versions: (.+)$", proc.stdout, flags=re.MULTILINE)
    if found:
        return platform, python, [v.strip() for v in found.group(1).split(",")]
    if "No matching distribution" in proc.stderr:
        return platform, python, []
    return platform, python, None  # pip could not ask the index: reported by the fixture


@pytest.fixture(scope="module")
def offered():
    """[(platform, python, bpy version)] for every bpy wheel on the index."""
    queries = [("linux-x64", py) for py in SCANNED_PYTHONS]
    queries += [(p, b.python) for p in PIP_PLATFORMS if p != "linux-x64" for b in BUILDS]
    with ThreadPoolExecutor(max_workers=8) as pool:
        answers = list(pool.map(lambda q: _offered(*q), queries))
    failed = [f"{p} Python {py}" for p, py, versions in answers if versions is None]
    if failed:
        missing_prerequisite(f"pip could not list the bpy wheels for {', '.join(failed)} (no network?)")
    found = [(p, py, v) for p, py, versions in answers for v in versions]
    return found


def _served(platform, python, version):
    builds = [b for b in BUILDS if b.covers(version) and b.python == python and platform in b.platforms]
    reasons = [e.reason for e in EXCLUDED if e.excludes(version, platform)]
    return builds, reasons


def test_every_blender_release_is_served_or_excluded_on_purpose(offered):
    unserved = []
    for platform, python, version in offered:
        builds, reasons = _served(platform, python, version)
        if not builds and not reasons:
            wrong = [b.name for b in BUILDS if b.covers(version)]
            why = f"in {', '.join(wrong)}'s range, built for another Python or platform" if wrong \
                else "in no build's range"
            unserved.append(f"Blender {version} (Python {python}, {platform}): {why}")
    assert not unserved, ("Blender releases that no extension build serves and EXCLUDED does not name "
                          "(solvers/extension_builds.py):\n" + "\n".join(sorted(set(unserved))))
    # The releases the install matrix tests are among those looked at (else the query lost them).
    linux = {v for p, _, v in offered if p == "linux-x64"}
    assert {v for v, _ in MATRIX} <= linux


def test_the_install_docs_have_a_row_for_every_release(offered):
    text = DOCS.read_text(encoding="utf-8")
    table = text[text.index("## Supported Blender versions"):]
    rows = {m.group(1) for m in re.finditer(r"^\| (\d+\.\d+)\b", table, flags=re.MULTILINE)}
    releases = {".".join(v.split(".")[:2]) for _, _, v in offered}
    served = {r for r in releases if version_tuple(r + ".0") >= version_tuple(BUILDS[0].blender_min)}
    assert served - rows == set(), f"docs/install.md's compatibility table has no row for {sorted(served - rows)}"
