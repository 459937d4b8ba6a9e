"""The extension builds (solvers/extension_builds.py) leave no Blender out and no cap on the next release,
and the wheel lock has what each build needs. Whether the released Blenders are all served is checked
against the bpy wheels on PyPI in tests/e2e/test_blender_coverage.py."""

import pytest

from facecap.solvers.extension_builds import (BUILDS, EXCLUDED, PLATFORMS, build_for_python, build_named,
                                              version_tuple)
from facecap.solvers.tools.build_extension import read_lock


def test_the_builds_ranges_meet_without_gap_or_overlap_and_the_newest_is_open():
    for older, newer in zip(BUILDS, BUILDS[1:]):
        assert older.blender_max == newer.blender_min, (older.name, newer.name)
        assert version_tuple(older.blender_min) < version_tuple(older.blender_max)
    assert BUILDS[-1].blender_max is None  # no cap excludes the next release by default
    for version in ("4.2.0", "4.5.15", "5.0.1", "5.1.0", "5.3.0", "5.4.0", "6.0.0"):
        assert sum(b.covers(version) for b in BUILDS) == 1, version
    assert not any(b.covers("4.1.1") for b in BUILDS)
    assert any(e.excludes("4.1.1", "linux-x64") for e in EXCLUDED)  # ... on purpose


def test_each_build_is_for_one_python_and_is_found_by_it():
    assert len({b.python for b in BUILDS}) == len(BUILDS)
    assert build_for_python((3, 11, 9)).name == "blender4.2-5.0"
    assert build_for_python("3.13").name == "blender5.1-and-newer"
    assert build_for_python((3, 12, 0)) is None
    assert build_named("blender5.1-and-newer").covers((5, 3, 0))
    with pytest.raises(KeyError, match="no extension build 'blender9'; the builds are blender4.2-5.0, "):
        build_named("blender9")
    assert all(set(b.platforms) <= set(PLATFORMS) for b in BUILDS)
    assert BUILDS[0].zip_name("0.1.0", "macos-x64") == "facecap-0.1.0-blender4.2-5.0-macos_x64.zip"


def test_the_lock_has_every_package_of_a_build_for_each_of_its_platforms():
    wheels, imports = read_lock()
    assert set(imports) == {"scipy", "cv2"}
    for build in BUILDS:
        mine = [w for w in wheels if w.python == build.python]
        packages = {w.name for w in mine}
        assert packages == {"scipy", "opencv-contrib-python-headless"}, build.name
        for platform in build.platforms:
            assert {w.name for w in mine if w.platform == platform} == packages, (build.name, platform)
        tag = "cp" + build.python.replace(".", "")
        for w in mine:  # compiled for that Python, or for the stable ABI it includes
            assert f"-{tag}-{tag}-" in w.file or "-abi3-" in w.file, w.file
