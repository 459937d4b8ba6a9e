# SPDX-License-Identifier: GPL-3.0-or-later
"""The built extension zip installs, enables and runs in a clean user folder, as a user would.

Blender itself is never imported in this process: every step runs in a fresh ``sys.executable``
subprocess with the ``bpy`` wheel, Blender's extension CLI (``blender_ext.py``, shipped inside the
wheel) builds and validates the zip, and the install runs with all of Blender's user folders pointed
at a temporary directory so the developer's own preferences and extensions are never touched.
"""

import importlib.util
import json
import os
import subprocess
import sys
import textwrap
import zipfile
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow

REPO = Path(__file__).resolve().parents[2]
TIMEOUT = 300

# Paths that are for developers only and must never ship in the extension zip.
DEV_ONLY_DIRS = ("tests/", ".ci/", ".git/", ".pytest_cache/", "sample_blends/", ".venv/", "docs/")
DEV_ONLY_FILES = ("pyproject.toml", ".git", ".gitignore")

INSTALL_SCRIPT = textwrap.dedent(
    """
    import json
    import sys

    import bpy

    zip_path, csv_path, result_path = sys.argv[1:4]
    result = {"version": list(bpy.app.version)}
    result["install"] = sorted(
        bpy.ops.extensions.package_install_files(
            filepath=zip_path, repo="user_default", enable_on_install=True
        )
    )
    result["addons"] = sorted(bpy.context.preferences.addons.keys())
    result["extensions_dir"] = bpy.utils.user_resource("EXTENSIONS")
    module = sys.modules.get("bl_ext.user_default.facecap")
    result["module_file"] = getattr(module, "__file__", None)

    operator = bpy.ops.facecap.import_markers
    try:
        operator.get_rna_type()
    except KeyError:
        result["operator"] = None
    else:
        cls = getattr(bpy.types, operator.idname())
        result["operator"] = cls.__module__
        objects_before = len(bpy.data.objects)
        result["run"] = sorted(operator(filepath=csv_path))
        result["objects_added"] = len(bpy.data.objects) - objects_before
    with open(result_path, "w", encoding="utf-8") as handle:
        json.dump(result, handle)
    """
)

MARKER_CSV = """frame,chin_x,chin_y,chin_z,lipL_x,lipL_y,lipL_z,nose_x,nose_y,nose_z
1,0.0,-0.05,0.0,0.02,-0.03,0.01,0.0,0.0,0.03
2,0.0,-0.051,0.0,0.021,-0.03,0.01,0.0,0.0,0.03
3,0.0,-0.053,0.0,0.022,-0.031,0.01,0.0,0.0,0.03
4,0.0,-0.052,0.0,0.021,-0.03,0.01,0.0,0.0,0.03
5,0.0,-0.05,0.0,0.02,-0.03,0.01,0.0,0.0,0.03
"""


def _run(args, *, env=None, cwd=None):
    proc = subprocess.run(
        [sys.executable, *map(str, args)],
        capture_output=True,
        text=True,
        timeout=TIMEOUT,
        env=env,
        cwd=cwd,
    )
    assert proc.returncode == 0, (
        f"{args[0]} exited with {proc.returncode}\nstdout:\n{proc.stdout}\nstderr:\n{proc.stderr}"
    )
    return proc


def _clean_env(user_root):
    """The current environment with every Blender user folder inside ``user_root``."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("BLENDER_")}
    env.pop("PYTHONPATH", None)  # the installed copy, not the repo, must provide the add-on
    env["BLENDER_USER_RESOURCES"] = str(user_root)
    for kind in ("CONFIG", "SCRIPTS", "EXTENSIONS", "DATAFILES"):
        env[f"BLENDER_USER_{kind}"] = str(user_root / kind.lower())
    return env


@pytest.fixture(scope="module")
def blender_ext():
    """``blender_ext.py`` inside the installed bpy wheel, found without importing bpy here."""
    spec = importlib.util.find_spec("bpy")
    if spec is None:
        pytest.skip("the bpy wheel is not installed in this environment")
    package_dir = Path(spec.origin).parent  # site-packages/bpy (origin is bpy/__init__.so)
    probe = _run(["-c", "import bpy; print('%d.%d' % bpy.app.version[:2])"])
    version = probe.stdout.strip().splitlines()[-1]
    cli = package_dir / version / "scripts" / "addons_core" / "bl_pkg" / "cli" / "blender_ext.py"
    assert cli.is_file(), f"Blender's extension CLI not found at {cli}"
    return cli


@pytest.fixture(scope="module")
def built_zip(blender_ext, tmp_path_factory):
    out = tmp_path_factory.mktemp("dist")
    _run([blender_ext, "build", "--source-dir", REPO, "--output-dir", out], cwd=out)
    zips = sorted(out.glob("*.zip"))
    assert len(zips) == 1, f"expected one zip in {out}, got {zips}"
    return zips[0]


def test_built_zip_validates(blender_ext, built_zip):
    _run([blender_ext, "validate", built_zip])


def test_built_zip_has_no_developer_files(built_zip):
    names = zipfile.ZipFile(built_zip).namelist()
    assert "blender_manifest.toml" in names
    assert "__init__.py" in names
    shipped = [
        n
        for n in names
        if n in DEV_ONLY_FILES
        or n.startswith(DEV_ONLY_DIRS)
        or "__pycache__/" in n
        or n.endswith(".pyc")
    ]
    assert shipped == [], f"developer-only files in the extension zip: {shipped}"


def test_install_enable_and_run_operator(built_zip, tmp_path):
    user_root = tmp_path / "blender_user"
    user_root.mkdir()
    csv_path = tmp_path / "take.csv"
    csv_path.write_text(MARKER_CSV, encoding="utf-8")
    result_path = tmp_path / "result.json"

    _run(
        ["-c", INSTALL_SCRIPT, built_zip, csv_path, result_path],
        env=_clean_env(user_root),
        cwd=tmp_path,
    )
    result = json.loads(result_path.read_text(encoding="utf-8"))

    assert result["install"] == ["FINISHED"]
    enabled = [name for name in result["addons"] if name.endswith(".facecap")]
    assert enabled == ["bl_ext.user_default.facecap"], result["addons"]
    # Installed into the temporary user folder, and imported from there (not from the repo).
    assert Path(result["extensions_dir"]).resolve().is_relative_to(user_root.resolve())
    assert result["module_file"] is not None
    module_file = Path(result["module_file"]).resolve()
    assert module_file.is_relative_to(user_root.resolve()), module_file

    assert result["operator"] is not None, (
        "bpy.ops.facecap.import_markers is not registered by the installed extension"
    )
    assert result["operator"].startswith("bl_ext.user_default.facecap"), result["operator"]
    assert result["run"] == ["FINISHED"]
