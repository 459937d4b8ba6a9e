"""Which files of a source checkout go into the extension zip: an explicit list, never "whatever sits there".

A checkout is also where people work: a take config, a capture, an ``out/`` folder of results, an editor's
backup, a developer's scratch notes. None of them may ride into a zip an artist installs, so the build copies
only what is named here (``build_extension.stage_source``): the add-on's two root modules, the Python files of
its three packages and the few data files the add-on reads at run time. The build adds what it generates
itself: the manifest, the locked wheels and the locked assets (plotly.js, the face-landmark models).

``tests/core/test_extension_files.py`` checks that every file git tracks under the packages is either Python
or listed in ``ADDON_DATA``, so a new data file cannot be forgotten silently.
"""

import shutil
from pathlib import Path

#: Root files of the extension (``blender_manifest.toml`` is generated per build, not copied).
ADDON_ROOT_FILES = ("__init__.py", "__main__.py")
#: The add-on's packages: each one's ``.py`` files, at any depth (``__pycache__`` left out).
ADDON_PACKAGES = ("facecap_addon", "operators", "solvers")
#: The packages' data files the add-on reads at run time (besides the build's locked assets).
ADDON_DATA = (
    "solvers/tools/report/assets/review.css",
    "solvers/tools/report/assets/review.js",
    "solvers/video/fusion_table.json",  # the blendshape scores' fusion with the landmark solve, per shape
    "solvers/video/fusion_map.npz",  # and its map across shapes
)


def addon_files(source):
    """The relative paths (POSIX strings, sorted) of the add-on's files in the checkout ``source``.

    Raises
    ------
    FileNotFoundError
        When a root file, package or data file of the lists above is missing (not a whole checkout).
    """
    source = Path(source)
    out = []
    for name in ADDON_ROOT_FILES + ADDON_DATA:
        if not (source / name).is_file():
            raise FileNotFoundError(f"{source / name}: missing from the checkout (an add-on file)")
        out.append(name)
    for package in ADDON_PACKAGES:
        root = source / package
        if not (root / "__init__.py").is_file():
            raise FileNotFoundError(f"{root}: not a package of the add-on (no __init__.py)")
        out += [p.relative_to(source).as_posix() for p in root.rglob("*.py")
                if "__pycache__" not in p.relative_to(source).parts and p.is_file()]
    return sorted(set(out))


def copy_addon(source, stage):
    """Copy the add-on's files (``addon_files``) from ``source`` into the folder ``stage``; returns their paths."""
    files = addon_files(source)
    for rel in files:
        target = Path(stage) / rel
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(Path(source) / rel, target)
    return files
