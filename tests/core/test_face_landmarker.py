"""The Face Landmarker bundle's models as facecap runs them (OpenCV's DNN module, the blendshape head in NumPy),
against the TensorFlow Lite runtime; finding, checking and downloading the bundle (a local web server: tests
never reach the network; the shared copy of the bundle is served)."""

import zipfile

import numpy as np
import pytest
from ict_release_copy import serve_release
from shared_data import FACE_LANDMARKER, require

from facecap.solvers.errors import FacecapError
from facecap.solvers.video.face_landmarker import BLENDSHAPE_NAMES, blendshape_scores, load_bundle_models
from facecap.solvers.video.landmarker_bundle import BUNDLE_SIZE, ENVIRONMENT, find_bundle, read_bundle
from facecap.solvers.video.tflite_graph import TFLiteGraph


@pytest.fixture(scope="module")
def bundle():
    return require(FACE_LANDMARKER)


def _litert(data):
    from ai_edge_litert.interpreter import Interpreter  # the reference runtime (test dependency)

    it = Interpreter(model_content=data, num_threads=1)
    it.allocate_tensors()
    return it


def _face_points(rng, n):
    """(n, 146, 2) plausible inputs of the blendshape head: a face's worth of points in pixels, jittered."""
    base = rng.normal(size=(1, 146, 2)) * [60.0, 75.0] + [320.0, 240.0]
    return (base + rng.normal(size=(n, 146, 2)) * 4.0).astype(np.float32)


def test_blendshape_head_in_numpy_matches_the_tflite_runtime(bundle):
    """The head run in NumPy, 40 inputs at once, gives the runtime's 52 scores one by one to 1e-5."""
    data = read_bundle(bundle)["blendshapes"]
    head = TFLiteGraph(data)
    x = _face_points(np.random.default_rng(3), 40)
    got = head(x, chunk=16)[0]
    it = _litert(data)
    want = []
    for xi in x:
        it.set_tensor(it.get_input_details()[0]["index"], xi[None])
        it.invoke()
        want.append(it.get_tensor(it.get_output_details()[0]["index"]).reshape(-1).copy())
    assert got.shape == (40, 52)
    np.testing.assert_allclose(got, np.array(want), atol=1e-5)
    assert np.ptp(np.array(want), axis=0).max() > 0.1  # the inputs do move the scores


def test_blendshape_scores_leave_gaps_and_read_mediapipes_146_points(bundle):
    """Frames with a missing point are NaN; only the 146 points of the head's subset matter."""
    _nets, head = load_bundle_models(bundle)
    rng = np.random.default_rng(4)
    pts = np.zeros((3, 478, 3))
    from facecap.solvers.video.face_landmarker import BLENDSHAPE_POINTS

    pts[:, list(BLENDSHAPE_POINTS), :2] = _face_points(rng, 3)
    pts[1, 470, 0] = np.nan
    other = pts.copy()
    other[:, 2, :] = 1e6  # landmark 2 is not one the head reads
    s = blendshape_scores(head, pts)
    assert np.isnan(s[1]).all() and np.isfinite(s[[0, 2]]).all()
    np.testing.assert_array_equal(np.isnan(blendshape_scores(head, other)), np.isnan(s))
    np.testing.assert_allclose(blendshape_scores(head, other)[[0, 2]], s[[0, 2]])
    assert len(BLENDSHAPE_NAMES) == s.shape[1] and BLENDSHAPE_NAMES[9] == "eyeBlinkLeft"


@pytest.mark.parametrize("role,size", [("detector", 128), ("landmarks", 256)])
def test_bundle_models_in_opencv_match_the_tflite_runtime(bundle, role, size):
    """OpenCV's DNN module runs the detector and the 478-point model as the runtime does (1e-3 of outputs up to
    ~200: the landmark model's crop pixels)."""
    nets, _head = load_bundle_models(bundle)
    data = read_bundle(bundle)[role]
    x = np.random.default_rng(5).random((1, size, size, 3), dtype=np.float32)
    net = nets[role]
    net.setInput(np.ascontiguousarray(x.transpose(0, 3, 1, 2)))
    outs = [o.reshape(-1) for o in net.forward(net.getUnconnectedOutLayersNames())]
    it = _litert(data)
    it.set_tensor(it.get_input_details()[0]["index"], x)
    it.invoke()
    for d in it.get_output_details():
        want = it.get_tensor(d["index"]).reshape(-1)
        got = next(o for o in outs if o.size == want.size and np.abs(o - want).max() < 1e-2 * (1 + np.abs(want).max()))
        np.testing.assert_allclose(got, want, atol=1e-3)


def test_tflite_graph_refuses_what_it_cannot_run(bundle):
    with zipfile.ZipFile(bundle) as z:
        detector = z.read("face_detector.tflite")
    with pytest.raises(FacecapError, match="not a TensorFlow Lite model"):
        TFLiteGraph(b"PK\x03\x04 not a model at all", name="x.tflite")
    with pytest.raises(FacecapError, match="face_detector.tflite: operator 19 .* is not one facecap runs"):
        TFLiteGraph(detector, name="face_detector.tflite")  # RELU (19), PAD, 3x3 convolutions: refused, not run wrongly
    head = TFLiteGraph(read_bundle(bundle)["blendshapes"], name="head")
    with pytest.raises(FacecapError, match=r"head: input must have shape \(N, 146, 2\); got \(2, 100, 2\)"):
        head(np.zeros((2, 100, 2)))


def test_bundle_is_found_and_hash_checked(bundle, tmp_path, monkeypatch):
    monkeypatch.setenv("FACECAP_CACHE", str(tmp_path / "cache"))
    monkeypatch.delenv(ENVIRONMENT, raising=False)
    assert find_bundle() is None  # nothing installed: the older models are used
    monkeypatch.setenv(ENVIRONMENT, str(bundle))
    assert find_bundle() == bundle
    monkeypatch.setenv(ENVIRONMENT, str(tmp_path / "nowhere.task"))
    with pytest.raises(FacecapError, match="FACECAP_FACE_LANDMARKER names .*nowhere.task, which is not a file"):
        find_bundle()
    with pytest.raises(FacecapError, match="no such file"):
        find_bundle(tmp_path / "missing.task")
    other = tmp_path / "other.task"
    data = bytearray(bundle.read_bytes())
    data[-100] ^= 1  # the same size, another digest
    other.write_bytes(bytes(data))
    with pytest.raises(FacecapError, match="other.task: not the Face Landmarker bundle .*landmark-models fetch"):
        read_bundle(other)


def test_fetch_downloads_checks_and_bounds_the_bundle(bundle, tmp_path, monkeypatch):
    """`landmark-models fetch` (from a local server): installed once, hash-checked; a download cut short, one that
    is not the bundle, or one past its deadline leaves nothing behind and names the address."""
    from facecap.solvers.tools.landmark_models import bundle_installed, fetch_bundle

    monkeypatch.setenv("FACECAP_CACHE", str(tmp_path / "cache"))
    out = tmp_path / "models" / "face_landmarker.task"
    with serve_release(bundle) as url:
        for path, match in (("/missing.zip", "could not download the Face Landmarker bundle.*Not Found"),
                            ("/cut.zip", "could not download the Face Landmarker bundle")):
            with pytest.raises(FacecapError, match=match) as caught:
                fetch_bundle(url + path, out)
            assert url + path in str(caught.value) and "in a browser" in str(caught.value)
            assert not out.parent.exists() or list(out.parent.iterdir()) == []
        with pytest.raises(FacecapError, match="took more than 0.3 s"):
            fetch_bundle(url + "/slow.zip", out, deadline=0.3)  # a megabyte every 0.2 s
        assert list(out.parent.iterdir()) == []
        seen = []
        assert fetch_bundle(url + "/ict.zip", out, progress=lambda d, t: seen.append((d, t))) == out
        assert bundle_installed(out) and [p.name for p in out.parent.iterdir()] == [out.name]
        assert seen[-1] == (BUNDLE_SIZE, BUNDLE_SIZE)
        assert fetch_bundle(url + "/missing.zip", out) == out  # installed: nothing downloaded
    other = tmp_path / "served" / "other.task"
    other.parent.mkdir()
    data = bytearray(bundle.read_bytes())
    data[-100] ^= 1
    other.write_bytes(bytes(data))
    with serve_release(other) as url:
        with pytest.raises(FacecapError, match="not the Face Landmarker bundle"):
            fetch_bundle(url + "/ict.zip", tmp_path / "b" / "face_landmarker.task")
        assert list((tmp_path / "b").iterdir()) == []
    big = tmp_path / "served" / "big.task"
    big.write_bytes(bundle.read_bytes() + b"\0" * 10)
    with serve_release(big) as url:
        with pytest.raises(FacecapError, match="sends 3,758,606 bytes, not the bundle's 3,758,596"):
            fetch_bundle(url + "/ict.zip", tmp_path / "c" / "face_landmarker.task")
        assert list((tmp_path / "c").iterdir()) == []


def test_landmark_models_info_says_which_models_a_take_uses(bundle, tmp_path, monkeypatch, capsys):
    from facecap.solvers.tools.landmark_models import main

    monkeypatch.setenv("FACECAP_CACHE", str(tmp_path / "cache"))
    monkeypatch.delenv(ENVIRONMENT, raising=False)
    assert main(["info"]) == 0
    assert "Face Landmarker bundle: not installed (`python -m facecap landmark-models fetch`" in capsys.readouterr().out
    monkeypatch.setenv(ENVIRONMENT, str(bundle))
    assert main(["info"]) == 0
    assert f"Face Landmarker bundle: {bundle}\n" in capsys.readouterr().out
