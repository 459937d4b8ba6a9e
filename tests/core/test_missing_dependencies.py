"""Missing scipy/OpenCV: every feature that needs them says which build to install, never a traceback."""

import json
import subprocess
import sys
import textwrap
import types

import pytest

from facecap.solvers import errors
from facecap.solvers.errors import FacecapError, MissingDependencyError, needs


@pytest.mark.parametrize("system, machine, expected", [
    ("Linux", "x86_64", "linux-x64"), ("Windows", "AMD64", "windows-x64"),
    ("Darwin", "arm64", "macos-arm64"), ("Darwin", "x86_64", "macos-x64"), ("Linux", "aarch64", "linux-arm64"),
])
def test_platform_names_follow_blender(monkeypatch, system, machine, expected):
    monkeypatch.setattr(errors.platform, "system", lambda: system)
    monkeypatch.setattr(errors.platform, "machine", lambda: machine)
    assert errors.blender_platform() == expected
    suffix = expected.replace("-", "_")
    # the zip of the Blenders that run this Python: Blender 4.2-5.0 run 3.11, 5.1 and newer 3.13
    assert errors.extension_zip_name((3, 11, 9)) == f"facecap-0.1.0-blender4.2-5.0-{suffix}.zip"
    assert errors.extension_zip_name((3, 13, 5)) == f"facecap-0.1.0-blender5.1-and-newer-{suffix}.zip"
    assert errors.extension_zip_name((3, 12, 0)) == f"facecap-0.1.0-<build for your Blender>-{suffix}.zip"


def test_inside_blender_the_message_names_the_zip_not_pip(monkeypatch):
    monkeypatch.setitem(sys.modules, "bpy", types.ModuleType("bpy"))
    monkeypatch.setitem(sys.modules, "cv2", None)  # import cv2 -> ImportError
    with pytest.raises(MissingDependencyError) as info, needs("cv2", "Video input"):
        import cv2  # noqa: F401
    message = str(info.value)
    assert message.startswith("Video input needs opencv-contrib-python-headless (cv2), which cannot be imported here")
    assert f"install the FaceCap build for this computer, {errors.extension_zip_name()}" in message
    assert "Install from Disk" in message and "pip" not in message
    assert isinstance(info.value, FacecapError)  # operators report it as one line


def test_outside_blender_the_message_gives_the_pip_package(monkeypatch):
    monkeypatch.delitem(sys.modules, "bpy", raising=False)
    monkeypatch.setitem(sys.modules, "scipy.ndimage", None)
    with pytest.raises(MissingDependencyError, match=r"needs scipy, which cannot.*pip install scipy$"), \
            needs("scipy", "Stable-marker scoring"):
        from scipy.ndimage import uniform_filter1d  # noqa: F401


# Each feature that needs scipy or OpenCV, run in a Python where neither can be imported.
PROBE = textwrap.dedent(
    """
    import json, sys
    for name in ("scipy", "cv2"):
        sys.modules[name] = None  # as in a Blender without the bundled wheels
    import numpy as np
    from facecap.solvers.errors import FacecapError
    from facecap.solvers.markers import MarkerSet

    rng = np.random.default_rng(0)
    pos = rng.normal(size=(200, 6, 3))
    pos[50:53, 2] = np.nan
    markers = MarkerSet(tuple(f"m{i}" for i in range(6)), np.arange(1, 201), pos, fps=60.0, units="mm")

    def temporal():
        from facecap.solvers.engine import solve_bounded
        solve_bounded(rng.normal(size=(18, 4)), rng.normal(size=(50, 18)), smoothing=(0.1, 0.1))

    def clean():
        from facecap.solvers.capture.cleaning import CleanSettings, clean
        clean(markers, CleanSettings(fill_spline=8))

    def stable():
        from facecap.solvers.capture.stable_markers import suggest_stable_markers
        suggest_stable_markers(markers)

    def video():
        from facecap.solvers.video.reading import Footage
        Footage(sys.argv[1])

    def rbf():
        import facecap.solvers.strategies.rbf  # noqa: F401

    out = {}
    for case in (temporal, clean, stable, video, rbf):
        try:
            case()
            out[case.__name__] = "ran"
        except FacecapError as exc:
            out[case.__name__] = f"{type(exc).__name__}: {exc}"
        except Exception as exc:
            out[case.__name__] = f"TRACEBACK {type(exc).__name__}: {exc}"
    print(json.dumps(out))
    """
)


def test_every_scipy_or_opencv_feature_fails_with_the_readable_error(tmp_path):
    clip = tmp_path / "face.avi"
    clip.write_bytes(b"")
    proc = subprocess.run([sys.executable, "-c", PROBE, str(clip)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    results = json.loads(proc.stdout.strip().splitlines()[-1])
    expected = {
        "temporal": "The temporal solve (smoothing over time) needs scipy",
        "clean": "Spline gap filling (Clean Markers) needs scipy",
        "stable": "Stable-marker scoring (Suggest Stable Markers, Detect Neutral) needs scipy",
        "video": "Video input (tracking, flow) needs opencv-contrib-python-headless",
        "rbf": "The rbf strategy needs scipy",
    }
    for case, start in expected.items():
        assert results[case].startswith(f"MissingDependencyError: {start}"), (case, results[case])
