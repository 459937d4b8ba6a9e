"""Every extension zip (each Blender generation, each platform) carries the face-landmark models, byte for byte
the files of the locked mediapipe wheel, with its licence, and nothing else of mediapipe (no wheel, no Python
code)."""

import zipfile

import pytest

from facecap.solvers.extension_builds import BUILDS
from facecap.solvers.tools.build_extension import fetch_assets, read_assets
from facecap.solvers.video.face_models import MODEL_FILES
from facecap.solvers.video.fusion import MAP_FILE_NAME, TABLE_FILE


@pytest.mark.parametrize("build, platform", [(b.name, p) for b in BUILDS for p in b.platforms])
def test_each_zip_carries_the_face_landmark_models(extension_zips, build, platform):
    assets = [a for a in read_assets() if a.name == "mediapipe"]
    files = sorted(a.target.rsplit("/", 1)[1] for a in assets)
    assert files == sorted([*MODEL_FILES.values(), "LICENSE-mediapipe.txt"])
    expected = fetch_assets(assets)
    with zipfile.ZipFile(extension_zips["zips"][(build, platform)]) as z:
        for asset, data in expected.items():
            assert z.read(asset.target) == data, asset.target
        assert not [n for n in z.namelist() if "mediapipe" in n.lower() and not n.endswith("LICENSE-mediapipe.txt")]
        # the Face Landmarker bundle is downloaded, not shipped; what runs it and the fusion table and map are
        assert z.read("solvers/video/fusion_table.json") == TABLE_FILE.read_bytes()
        assert z.read("solvers/video/fusion_map.npz") == TABLE_FILE.with_name(MAP_FILE_NAME).read_bytes()
        assert "solvers/video/tflite_graph.py" in z.namelist()
        assert not [n for n in z.namelist() if n.endswith(".task")]
    assert b"Apache License" in expected[next(a for a in assets if a.target.endswith(".txt"))]
