"""The extension zips carry the face-landmark models, byte for byte the files of the locked mediapipe wheel,
with its licence, and nothing else of mediapipe (no wheel, no Python code)."""

import zipfile

import pytest

from facecap.solvers.tools.build_extension import PLATFORMS, fetch_assets, read_assets
from facecap.solvers.video.face_models import MODEL_FILES


@pytest.mark.parametrize("platform", PLATFORMS)
def test_each_zip_carries_the_face_landmark_models(extension_zips, platform):
    assets = [a for a in read_assets() if a.name == "mediapipe"]
    files = sorted(a.target.rsplit("/", 1)[1] for a in assets)
    assert files == sorted([*MODEL_FILES.values(), "LICENSE-mediapipe.txt"])
    expected = fetch_assets(assets)
    with zipfile.ZipFile(extension_zips["zips"][platform]) as z:
        for asset, data in expected.items():
            assert z.read(asset.target) == data, asset.target
        assert not [n for n in z.namelist() if "mediapipe" in n.lower() and not n.endswith("LICENSE-mediapipe.txt")]
    assert b"Apache License" in expected[next(a for a in assets if a.target.endswith(".txt"))]
