"""The extension zip is built from an explicit list of the add-on's files: whatever else sits in a checkout (a take
config, a capture, ``out/``, earlier zips, a stale model file) never enters it; and the manifest is ready for the
Blender Extensions platform (issue 40)."""

import importlib.util
import shutil
import subprocess
import tomllib
from pathlib import Path

import pytest

from facecap.solvers.tools.build_extension import stage_source
from facecap.solvers.tools.extension_files import ADDON_DATA, ADDON_PACKAGES, ADDON_ROOT_FILES, addon_files

REPO = Path(__file__).resolve().parents[2]
MANIFEST = tomllib.loads((REPO / "blender_manifest.toml").read_text(encoding="utf-8"))

#: What a user or developer leaves in a checkout (issue 40 found the first three in a zip: 112.7 instead of 109.5 MB).
STRAYS = ("facial_sing.toml", "Facial-Sing.c3d", "out/facial_sing.blend", "out/weights.csv", "dist/old.zip",
          "zips/facecap-0.1.0-linux_x64.zip", "tests/test_x.py", "sample_blends/character.blend", ".git/HEAD",
          ".venv/bin/python", "facecap-batch.json", "notes.md", "solvers/take.c3d", "solvers/notes.txt",
          "solvers/__pycache__/errors.cpython-311.pyc", "facecap_addon/cli.py.orig", "operators/.solve.py.swp",
          "solvers/video/models/face_landmark.tflite", "solvers/tools/report/assets/plotly.min.js",
          "facecap_addon/render/out/frame.png")


def _checkout(root):
    """A copy of the add-on's files with the manifest: a checkout as the build sees it."""
    for rel in addon_files(REPO) + ["blender_manifest.toml"]:
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(REPO / rel, root / rel)
    return root


def test_a_stray_file_in_the_checkout_never_enters_the_staged_extension(tmp_path):
    source = _checkout(tmp_path / "checkout")
    for rel in STRAYS:
        (source / rel).parent.mkdir(parents=True, exist_ok=True)
        (source / rel).write_bytes(b"not the add-on's")
    stage = tmp_path / "stage"
    stage.mkdir()
    stage_source(stage, [], ["linux-x64"], source=source)
    staged = sorted(p.relative_to(stage).as_posix() for p in stage.rglob("*") if p.is_file())
    assert staged == sorted(addon_files(REPO) + ["blender_manifest.toml"])
    assert not set(STRAYS) & set(staged)
    assert (stage / "wheels").is_dir() and not any((stage / "wheels").iterdir())


def test_the_list_is_the_add_on_python_files_and_its_named_data():
    files = addon_files(REPO)
    assert set(ADDON_ROOT_FILES) | set(ADDON_DATA) <= set(files)
    assert {"facecap_addon/cli.py", "operators/__init__.py", "solvers/engine/__init__.py"} <= set(files)
    others = [f for f in files if not f.endswith(".py") and f not in ADDON_DATA]
    assert others == []
    assert all(f in ADDON_ROOT_FILES or f.startswith(tuple(p + "/" for p in ADDON_PACKAGES)) for f in files)


def test_every_tracked_file_of_the_packages_is_python_or_named_as_data():
    """A data file added to the add-on (a new .css, a lookup table) must be added to ``ADDON_DATA`` too, or
    the zip would lack it: git's list of the packages' files is the reference."""
    if not (REPO / ".git").exists() or shutil.which("git") is None:
        pytest.skip("not a git checkout: the tracked files cannot be listed")
    tracked = subprocess.run(["git", "ls-files", "--", *ADDON_PACKAGES], cwd=REPO, capture_output=True, text=True,
                             check=True, timeout=60).stdout.split()
    unlisted = [f for f in tracked if not f.endswith(".py") and f not in ADDON_DATA]
    assert unlisted == [], f"tracked add-on files missing from extension_files.ADDON_DATA: {unlisted}"
    assert set(f for f in tracked if f.endswith(".py")) <= set(addon_files(REPO))


def test_a_checkout_missing_an_add_on_file_is_one_clear_error(tmp_path):
    from facecap.solvers.tools.build_extension import BuildError

    source = _checkout(tmp_path / "checkout")
    (source / ADDON_DATA[0]).unlink()
    with pytest.raises(BuildError, match=r"review\.css: missing from the checkout .*build from a whole source checkout"):
        stage_source(tmp_path, [], ["linux-x64"], source=source)


def test_the_manifest_is_ready_for_the_extensions_platform():
    """What extensions.blender.org asks of a manifest: a GPL-3.0-or-later licence with a copyright line, a
    website, tags from Blender's list, and each permission explained in at most 64 characters without a
    closing stop (the build's ``blender_ext.py validate`` checks the same with Blender's own tag list)."""
    assert MANIFEST["license"] == ["SPDX:GPL-3.0-or-later"] and MANIFEST["copyright"]
    assert MANIFEST["website"].startswith("https://github.com/")
    assert MANIFEST["type"] == "add-on" and len(MANIFEST["tagline"]) <= 64 and MANIFEST["tagline"][-1].isalnum()
    assert set(MANIFEST["permissions"]) == {"files", "network"}
    for why in MANIFEST["permissions"].values():
        assert 10 < len(why) <= 64 and why[-1].isalnum(), why
    spec = importlib.util.find_spec("bpy")
    tags_py = None if spec is None or spec.origin is None else next(
        Path(spec.origin).parent.glob("*/scripts/modules/_bpy_internal/extensions/tags.py"), None)
    if tags_py is not None:  # Blender's own list, read without importing bpy
        namespace = {}
        exec(compile(tags_py.read_text(encoding="utf-8"), str(tags_py), "exec"), namespace)
        assert set(MANIFEST["tags"]) <= namespace["addons"], MANIFEST["tags"]
    assert {"Animation", "Import-Export"} <= set(MANIFEST["tags"])


def test_checkout_outputs_are_ignored_by_git():
    ignored = (REPO / ".gitignore").read_text(encoding="utf-8").split()
    assert {"out/", "dist/", "facecap-demo/", "*.zip", "facecap-batch.json"} <= set(ignored)
