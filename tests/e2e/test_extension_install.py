# SPDX-License-Identifier: GPL-3.0-or-later
"""``python -m facecap build-extension``: a validated zip per Blender generation and platform, each with its
wheels and nothing else, declaring the Blender versions it is for.

The build runs as a user would run it (a subprocess of the CLI; wheels cached in ``~/.cache/facecap``).
Installing and using the linux-x64 zips in real Blender releases is ``test_install_matrix.py``.
"""

import re
import tomllib
import zipfile
from pathlib import Path

import pytest
from matrix_env import MATRIX

from facecap.solvers.extension_builds import BUILDS, build_named
from facecap.solvers.tools.build_extension import SIZE_TARGET_MB, BuildError, generated_manifest, read_lock, sha256_of

pytestmark = pytest.mark.slow

REPO = Path(__file__).resolve().parents[2]

# Paths that are for developers only and must never ship in the extension zip.
DEV_ONLY_DIRS = ("tests/", ".ci/", ".git/", ".pytest_cache/", "sample_blends/", ".venv/", "docs/", "dist/")
DEV_ONLY_FILES = ("pyproject.toml", ".git", ".gitignore", "wheels.lock.toml", "README.md")


ZIPS = [(b.name, p) for b in BUILDS for p in b.platforms]


def test_one_validated_zip_per_build_and_platform_under_the_size_target(extension_zips):
    zips = extension_zips["zips"]
    assert sorted(zips) == sorted(ZIPS), extension_zips["stdout"]
    for (build, platform), path in zips.items():
        assert path.name == f"facecap-0.1.0-{build}-{platform.replace('-', '_')}.zip"
        size_mb = path.stat().st_size / 1e6
        assert f"({size_mb:.1f} MB, validated)" in extension_zips["stdout"]
        assert size_mb <= SIZE_TARGET_MB, f"{path.name} is {size_mb:.1f} MB"


@pytest.mark.parametrize("build, platform", ZIPS)
def test_each_zip_holds_its_locked_wheels_unmodified_and_its_blender_range(extension_zips, build, platform, tmp_path):
    wheels, imports = read_lock()
    target = build_named(build)
    expected = {w.file: w.sha256 for w in wheels if w.platform == platform and w.python == target.python}
    with zipfile.ZipFile(extension_zips["zips"][(build, platform)]) as z:
        names = z.namelist()
        shipped = sorted(n for n in names if n.startswith("wheels/"))
        assert shipped == sorted(f"wheels/{f}" for f in expected)
        for name in shipped:  # byte for byte the PyPI file
            z.extract(name, tmp_path)
            assert sha256_of(tmp_path / name) == expected[name.removeprefix("wheels/")]
        manifest = tomllib.loads(z.read("blender_manifest.toml").decode())
    assert not any("numpy" in n.lower() for n in shipped)
    assert manifest["blender_version_min"] == target.blender_min
    assert manifest.get("blender_version_max") == target.blender_max  # the newest build's range is open
    # every wheel is for the Python of the Blenders in that range (cpXY, or the stable ABI)
    tag = "cp" + target.python.replace(".", "")
    assert all(f"-{tag}-{tag}-" in n or "-abi3-" in n for n in shipped), shipped
    assert manifest["build"]["generated"]["platforms"] == [platform]
    assert sorted(manifest["build"]["generated"]["wheels"]) == sorted(f"./wheels/{f}" for f in expected)
    # The wheels provide the modules the lock says they do (the import-walk test trusts that list).
    tops = set()
    for name in shipped:
        with zipfile.ZipFile(tmp_path / name) as wheel:
            tops |= {n.split("/")[0] for n in wheel.namelist()}
    assert set(imports) <= tops


@pytest.mark.parametrize("build, platform", ZIPS)
def test_zip_holds_the_addon_files_and_nothing_else(extension_zips, build, platform):
    """Exactly the add-on's files (``extension_files.addon_files``), the generated manifest, the build's wheels
    and the locked assets: nothing a checkout may hold besides (issue 40: a take, a capture, ``out/``)."""
    from facecap.solvers.tools.build_extension import read_assets
    from facecap.solvers.tools.extension_files import addon_files

    names = [n for n in zipfile.ZipFile(extension_zips["zips"][(build, platform)]).namelist() if not n.endswith("/")]
    assert {"blender_manifest.toml", "__init__.py", "operators/__init__.py", "solvers/engine/__init__.py"} <= set(names)
    shipped = [n for n in names if n in DEV_ONLY_FILES or n.startswith(DEV_ONLY_DIRS) or "__pycache__/" in n
               or n.endswith(".pyc")]
    assert shipped == [], f"developer-only files in the extension zip: {shipped}"
    generated = {"blender_manifest.toml"} | {a.target for a in read_assets()}
    rest = sorted(n for n in names if not n.startswith("wheels/") and n not in generated)
    assert rest == addon_files(REPO)


def test_the_release_files_sum_every_zip_and_install_md_gives_their_sizes(extension_zips):
    """``--release`` wrote SHA256SUMS (each zip's real hash) and the notes' table; docs/install.md's table gives
    each zip's size within 0.3 MB (the add-on's Python moves a zip by kilobytes a commit; issue 40 found the
    page 4 MB low): ``python -m facecap build-extension --docs docs/install.md`` rewrites it."""
    from facecap.solvers.tools import release

    zips = extension_zips["zips"]
    sums = dict(reversed(line.split("  ")) for line in (extension_zips["dist"] / release.CHECKSUMS).read_text().splitlines())
    assert sums == {p.name: sha256_of(p) for p in zips.values()}
    notes = (extension_zips["dist"] / release.NOTES).read_text()
    page = (REPO / "docs" / "install.md").read_text(encoding="utf-8")
    table = page.split(release.BEGIN, 1)[1].split(release.END, 1)[0]
    for path in zips.values():
        assert f"`{path.name}` ({path.stat().st_size / 1e6:.1f} MB)" in notes
        documented = float(re.search(rf"`{re.escape(path.name)}` \((\d+\.\d) MB\)", table).group(1))
        assert abs(documented - path.stat().st_size / 1e6) <= 0.3, (path.name, documented)


def test_wheel_lists_and_blender_ranges_are_generated_never_written_in_the_repository():
    text = (REPO / "blender_manifest.toml").read_text(encoding="utf-8")
    repo = tomllib.loads(text)
    assert "wheels" not in repo and "platforms" not in repo and "blender_version_max" not in repo
    assert repo["blender_version_min"] == BUILDS[0].blender_min  # a source checkout linked into Blender
    old, new = BUILDS[0], BUILDS[-1]
    out = tomllib.loads(generated_manifest(text, ["./wheels/a-1-cp311-cp311-win_amd64.whl"], ["windows-x64"], old))
    assert out["wheels"] == ["./wheels/a-1-cp311-cp311-win_amd64.whl"] and out["platforms"] == ["windows-x64"]
    assert (out["blender_version_min"], out["blender_version_max"]) == ("4.2.0", "5.1.0")
    assert out["permissions"] == repo["permissions"]  # the tables after it are kept
    out = tomllib.loads(generated_manifest(text, [], ["linux-x64"], new))
    assert out["blender_version_min"] == "5.1.0" and "blender_version_max" not in out
    with pytest.raises(BuildError, match="`wheels` is generated by build-extension"):
        generated_manifest('wheels = ["./wheels/x.whl"]\n' + text, [], [])
    with pytest.raises(BuildError, match="`blender_version_max` is generated by build-extension"):
        generated_manifest(text.replace('blender_version_min = "4.2.0"',
                                        'blender_version_min = "4.2.0"\nblender_version_max = "5.1.0"'), [], [])


def test_a_tampered_cached_wheel_is_fetched_again(tmp_path):
    """A cached file whose hash does not match the lock is never used: it is downloaded again (here the
    package does not exist, so the build stops with the reason)."""
    from facecap.solvers.tools.build_extension import LockedWheel, fetch_wheels

    store = tmp_path / "wheels"
    store.mkdir()
    good = store / "facecap_no_such_package-1.0-py3-none-any.whl"
    good.write_bytes(b"the real bytes")
    wheel = LockedWheel("facecap-no-such-package", "1.0", "3.11", "linux-x64", good.name, sha256_of(good),
                        good.stat().st_size)
    assert fetch_wheels([wheel], tmp_path)[good.name] == good  # cached and matching: used as is
    good.write_bytes(b"tampered")
    with pytest.raises(BuildError, match="could not download facecap_no_such_package-1.0-py3-none-any.whl"):
        fetch_wheels([wheel], tmp_path)  # not on PyPI: the download fails, the bad file is not used


@pytest.mark.parametrize("build, platform", ZIPS)
def test_each_zip_carries_plotly_js_for_the_review_page(extension_zips, build, platform):
    """The sidebar's Export Review Report works in a real Blender: plotly.js is in the add-on itself,
    byte for byte the file of the locked plotly wheel (no plotly package installed)."""
    from facecap.solvers.tools.build_extension import fetch_assets, read_assets

    (asset,) = [a for a in read_assets() if a.name == "plotly"]
    expected = fetch_assets([asset])[asset]
    with zipfile.ZipFile(extension_zips["zips"][(build, platform)]) as z:
        assert z.read(asset.target) == expected
        assert not [n for n in z.namelist() if n.startswith("wheels/plotly")]
    assert expected.startswith(b"/**") and len(expected) > 3_000_000


@pytest.mark.parametrize("build", [b.name for b in BUILDS])
def test_the_bundled_wheels_accept_the_numpy_of_the_blenders_they_are_for(build):
    """Each build's SciPy and OpenCV declare (Requires-Dist) that they work with the NumPy every tested
    Blender in the build's range ships: 1.24.3 and 1.26.4 for 4.2-5.0, 2.3.4 for 5.1 and newer."""
    from packaging.requirements import Requirement

    from facecap.solvers.tools.build_extension import fetch_wheels

    target = build_named(build)
    numpys = sorted({numpy for version, numpy in MATRIX if target.covers(version)})
    assert numpys, f"the install matrix tests no Blender of the {build} build"
    wheels = [w for w in read_lock()[0] if w.python == target.python and w.platform == "linux-x64"]
    paths = fetch_wheels(wheels)
    for w in wheels:
        with zipfile.ZipFile(paths[w.file]) as z:
            meta = z.read(next(n for n in z.namelist() if n.endswith(".dist-info/METADATA"))).decode()
        needs = [Requirement(line.split(":", 1)[1].strip()) for line in meta.splitlines()
                 if line.startswith("Requires-Dist:")]
        numpy = [r for r in needs if r.name == "numpy"
                 and (r.marker is None or r.marker.evaluate({"python_version": target.python, "extra": ""}))]
        assert numpy, (w.file, needs)  # pip installs only where every one of them holds
        for r in numpy:
            assert all(r.specifier.contains(v) for v in numpys), (w.file, str(r), numpys)
