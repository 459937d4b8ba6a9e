"""``python -m facecap.solvers.tools.bench.landmarker_runtimes [VIDEO]``: the Face Landmarker's models as facecap
runs them (OpenCV's DNN module, the blendshape head in NumPy) beside the TensorFlow Lite runtime
(``ai-edge-litert``, when installed) and MediaPipe itself (when installed): milliseconds per model call on
one thread (medians, the same run), how far their outputs agree, and with a video, the whole pipeline against
MediaPipe's FaceLandmarker in video mode (landmarks in pixels, blendshape scores).

The bundle is ``$FACECAP_FACE_LANDMARKER`` or the installed one (``landmark-models fetch``).
"""

import argparse
import importlib.util
import time

import numpy as np

from ...errors import FacecapError
from ...video.face_landmarker import BLENDSHAPE_POINTS, load_bundle_models
from ...video.landmarker_bundle import find_bundle, read_bundle
from ...video.landmarks import track_landmarks
from ...video.reading import opencv

SIZES = {"detector": 128, "landmarks": 256}


def _median_ms(call, repeats=30):
    call()
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        call()
        times.append(time.perf_counter() - t)
    return 1000.0 * float(np.median(times))


def models_side_by_side(bundle, log=print):
    """Per model: ms per call here and in the runtime, and the largest output difference."""
    cv2 = opencv()
    cv2.setNumThreads(1)
    nets, head = load_bundle_models(bundle)
    data = read_bundle(bundle)
    litert = importlib.util.find_spec("ai_edge_litert") is not None
    rng = np.random.default_rng(0)
    for role, size in SIZES.items():
        x = rng.random((1, size, size, 3), dtype=np.float32)
        net = nets[role]

        def ours(net=net, x=x):
            net.setInput(np.ascontiguousarray(x.transpose(0, 3, 1, 2)))
            return [o.reshape(-1) for o in net.forward(net.getUnconnectedOutLayersNames())]

        line = f"{role}: OpenCV {cv2.__version__} {_median_ms(ours):.2f} ms"
        if litert:
            it, run = _interpreter(data[role], x)
            want = run()
            got = ours()
            diff = max(min(np.abs(g - w).max() for g in got if g.size == w.size) for w in want)
            line += f"; ai-edge-litert {_median_ms(run):.2f} ms; largest difference {diff:.1e}"
        log(line)
    pts = (rng.normal(size=(1, 146, 2)) * [60, 75] + [320, 240]).astype(np.float32)
    batch = pts + rng.normal(size=(64, 146, 2)).astype(np.float32) * 4
    line = (f"blendshape head: NumPy {_median_ms(lambda: head(pts)):.2f} ms one by one, "
            f"{_median_ms(lambda: head(batch), 5) / len(batch):.2f} ms a frame 64 at once")
    if litert:
        it, run = _interpreter(data["blendshapes"], pts)
        diff = np.abs(run()[0].reshape(-1) - head(pts)[0].reshape(-1)).max()
        line += f"; ai-edge-litert {_median_ms(run):.2f} ms; largest difference {diff:.1e}"
    log(line)
    cv2.setNumThreads(-1)


def _interpreter(data, x):
    from ai_edge_litert.interpreter import Interpreter  # the reference runtime: only when installed

    it = Interpreter(model_content=data, num_threads=1)
    it.allocate_tensors()
    index = it.get_input_details()[0]["index"]

    def run():
        it.set_tensor(index, x)
        it.invoke()
        return [it.get_tensor(d["index"]).reshape(-1) for d in it.get_output_details()]

    return it, run


def against_mediapipe(bundle, video, log=print):
    """facecap's landmarks and scores of ``video`` beside MediaPipe's FaceLandmarker (video mode)."""
    import mediapipe as mp  # only when installed: the reference pipeline
    from mediapipe.tasks.python import BaseOptions, vision  # as mediapipe

    cv2 = opencv()
    options = vision.FaceLandmarkerOptions(base_options=BaseOptions(model_asset_path=str(bundle)),
                                           running_mode=vision.RunningMode.VIDEO, output_face_blendshapes=True)
    marker = vision.FaceLandmarker.create_from_options(options)
    cap = cv2.VideoCapture(str(video))
    fps = cap.get(cv2.CAP_PROP_FPS) or 30.0
    pts, scores, times = [], [], []
    while (got := cap.read())[0]:
        h, w = got[1].shape[:2]
        image = mp.Image(image_format=mp.ImageFormat.SRGB, data=cv2.cvtColor(got[1], cv2.COLOR_BGR2RGB))
        t = time.perf_counter()
        r = marker.detect_for_video(image, int(len(pts) * 1000 / fps))
        times.append(time.perf_counter() - t)
        face = r.face_landmarks[0] if r.face_landmarks else None
        pts.append([[p.x * w, p.y * h] for p in face] if face else np.full((478, 2), np.nan))
        scores.append([c.score for c in r.face_blendshapes[0]] if face else np.full(52, np.nan))
    cap.release()
    t = time.perf_counter()
    ours = track_landmarks(video, bundle=bundle, smoothing=False)
    ours_s = (time.perf_counter() - t) / len(pts)
    err = np.linalg.norm(np.asarray(pts) - ours.raw[:, :, :2], axis=2)
    face_width = np.nanmedian(np.ptp(ours.raw[:, BLENDSHAPE_POINTS, 0], axis=1))
    d = np.abs(np.asarray(scores) - ours.blendshapes)
    log(f"whole pipeline, {len(pts)} frames: MediaPipe {1000 * np.median(times):.1f} ms a frame, facecap "
        f"{1000 * ours_s:.1f} ms (decoding included); landmarks apart by median {np.nanmedian(err):.2f} px, 95th "
        f"percentile {np.nanpercentile(err, 95):.2f} px (face {face_width:.0f} px wide); blendshape scores apart by "
        f"median {np.nanmedian(d):.4f}, 95th percentile {np.nanpercentile(d, 95):.3f}")


def main(argv=None):
    parser = argparse.ArgumentParser(prog="python -m facecap.solvers.tools.bench.landmarker_runtimes")
    parser.add_argument("video", nargs="?", help="also compare the whole pipeline with MediaPipe's on this video")
    args = parser.parse_args(argv)
    bundle = find_bundle()
    if bundle is None:
        raise FacecapError("no Face Landmarker bundle: `python -m facecap landmark-models fetch` or set "
                           "$FACECAP_FACE_LANDMARKER")
    models_side_by_side(bundle)
    if args.video and importlib.util.find_spec("mediapipe") is not None:
        against_mediapipe(bundle, args.video)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
