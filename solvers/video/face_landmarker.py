"""MediaPipe's Face Landmarker run frame by frame: the bundle's detector and 478-point landmark model in
OpenCV's DNN module, its blendshape head in NumPy (``tflite_graph``) over a whole clip at once.

The steps are MediaPipe's (``face_landmarker_graph``): BlazeFace finds the face when none is followed
(the same detector as the older face mesh, ``face_mesh.FaceMesh.detect``); the region around it, rotated
so the eyes are level and 1.5 times larger, is resampled to 256x256 (values 0-1) and gives 478 points
(x, y, depth) with a face score; the next frame's region is the box of these points. The irises come
with the landmarks (no second model). The blendshape head reads 146 of the points in the frame's pixels
(``BLENDSHAPE_POINTS``) and gives 52 scores named as ARKit names its shapes (``_neutral`` first).

Why OpenCV and NumPy rather than the TensorFlow Lite runtime (measured, docs/video.md): OpenCV is
already in every facecap install, on every platform of both Blender generations; ``ai-edge-litert``
has no Intel-Mac wheel and adds 13-22 MB a platform with its dependencies, ``mediapipe`` 35 MB and a
second OpenCV. The landmark model is 1.5x slower in OpenCV than in the runtime (7 against 5 ms) and
agrees with it to 4e-4 px of its 256-pixel crop; the blendshape head agrees to 3e-6.
"""

import numpy as np

from ..errors import FacecapError
from .face_mesh import N_POINTS, FaceMesh, anchors
from .landmarker_bundle import read_bundle
from .reading import opencv
from .tflite_graph import TFLiteGraph

LANDMARK_SIZE = 256
#: The 146 landmarks the blendshape head reads (MediaPipe's ``face_blendshapes_graph``), in its order.
BLENDSHAPE_POINTS = (
    0, 1, 4, 5, 6, 7, 8, 10, 13, 14, 17, 21, 33, 37, 39, 40, 46, 52, 53, 54, 55, 58, 61, 63, 65, 66, 67, 70, 78, 80,
    81, 82, 84, 87, 88, 91, 93, 95, 103, 105, 107, 109, 127, 132, 133, 136, 144, 145, 146, 148, 149, 150, 152, 153,
    154, 155, 157, 158, 159, 160, 161, 162, 163, 168, 172, 173, 176, 178, 181, 185, 191, 195, 197, 234, 246, 249,
    251, 263, 267, 269, 270, 276, 282, 283, 284, 285, 288, 291, 293, 295, 296, 297, 300, 308, 310, 311, 312, 314,
    317, 318, 321, 323, 324, 332, 334, 336, 338, 356, 361, 362, 365, 373, 374, 375, 377, 378, 379, 380, 381, 382,
    384, 385, 386, 387, 388, 389, 390, 397, 398, 400, 402, 405, 409, 415, 454, 466, 468, 469, 470, 471, 472, 473,
    474, 475, 476, 477)
#: The blendshape head's 52 outputs, in order (``_neutral`` is not a shape).
BLENDSHAPE_NAMES = (
    "_neutral", "browDownLeft", "browDownRight", "browInnerUp", "browOuterUpLeft", "browOuterUpRight", "cheekPuff",
    "cheekSquintLeft", "cheekSquintRight", "eyeBlinkLeft", "eyeBlinkRight", "eyeLookDownLeft", "eyeLookDownRight",
    "eyeLookInLeft", "eyeLookInRight", "eyeLookOutLeft", "eyeLookOutRight", "eyeLookUpLeft", "eyeLookUpRight",
    "eyeSquintLeft", "eyeSquintRight", "eyeWideLeft", "eyeWideRight", "jawForward", "jawLeft", "jawOpen", "jawRight",
    "mouthClose", "mouthDimpleLeft", "mouthDimpleRight", "mouthFrownLeft", "mouthFrownRight", "mouthFunnel",
    "mouthLeft", "mouthLowerDownLeft", "mouthLowerDownRight", "mouthPressLeft", "mouthPressRight", "mouthPucker",
    "mouthRight", "mouthRollLower", "mouthRollUpper", "mouthShrugLower", "mouthShrugUpper", "mouthSmileLeft",
    "mouthSmileRight", "mouthStretchLeft", "mouthStretchRight", "mouthUpperUpLeft", "mouthUpperUpRight",
    "noseSneerLeft", "noseSneerRight")


def load_bundle_models(bundle):
    """({"detector", "landmarks"}: cv2.dnn.Net, the blendshape head as a TFLiteGraph) of the bundle at
    ``bundle`` (a path; hash-checked)."""
    cv2 = opencv()
    data = read_bundle(bundle)
    nets = {}
    for role in ("detector", "landmarks"):
        try:
            net = cv2.dnn.readNetFromTFLite(np.frombuffer(data[role], np.uint8))
        except cv2.error as exc:
            raise FacecapError(f"{bundle}: its {role} model cannot be loaded by OpenCV {cv2.__version__} "
                               f"({str(exc).strip()[-160:]})") from None
        net.setPreferableBackend(cv2.dnn.DNN_BACKEND_OPENCV)
        net.setPreferableTarget(cv2.dnn.DNN_TARGET_CPU)
        nets[role] = net
    return nets, TFLiteGraph(data["blendshapes"], name=f"{bundle}: face_blendshapes.tflite")


class FaceLandmarker(FaceMesh):
    """Follows one face through frames with the bundle's models: ``FaceLandmarker(bundle)(frame) -> FaceFrame``
    (478 points with the irises; :meth:`blendshapes` scores a clip's points afterwards)."""

    def __init__(self, bundle, *, presence=0.5, min_detection=0.5):
        self.nets, self.head = load_bundle_models(bundle)
        self.presence, self.min_detection, self.iris = float(presence), float(min_detection), True
        self.anchors = anchors()
        self.region = None

    def finish(self, rgb, points):
        """Nothing left to do: the landmark model gives the irises and lids itself."""

    def mesh(self, rgb, region):
        """((478, 3) points in frame pixels, face score) in ``region``."""
        crop = region.crop(rgb, LANDMARK_SIZE).astype(np.float32) / 255.0
        net = self.nets["landmarks"]
        net.setInput(np.ascontiguousarray(crop.transpose(2, 0, 1)[None]))
        names = net.getUnconnectedOutLayersNames()
        outs = dict(zip(names, net.forward(names)))
        raw = next(o for o in outs.values() if o.size == 3 * N_POINTS).reshape(N_POINTS, 3)
        flag = float(outs["Identity_1"].reshape(-1)[0]) if "Identity_1" in outs else 10.0
        points = np.empty((N_POINTS, 3))
        points[:, :2] = region.to_frame(raw[:, :2], LANDMARK_SIZE)
        points[:, 2] = raw[:, 2] / LANDMARK_SIZE * region.size
        return points, float(1.0 / (1.0 + np.exp(-np.clip(flag, -100, 100))))

    def _run(self, role, tensor):  # the detector, as in FaceMesh
        net = self.nets[role]
        net.setInput(np.ascontiguousarray(tensor.transpose(2, 0, 1)[None], dtype=np.float32))
        return [o.reshape(-1) for o in net.forward(net.getUnconnectedOutLayersNames())]

    def blendshapes(self, points):
        """(F, 52) scores of ``points`` (F, 478, >=2) in pixels (NaN rows stay NaN): :data:`BLENDSHAPE_NAMES`."""
        return blendshape_scores(self.head, points)


def blendshape_scores(head, points):
    """(F, 52) scores of the blendshape head ``head`` (TFLiteGraph) for ``points`` (F, 478, >=2) in pixels;
    frames with a missing point are NaN."""
    pts = np.asarray(points, dtype=np.float64)[:, BLENDSHAPE_POINTS, :2]
    ok = np.isfinite(pts).all(axis=(1, 2))
    out = np.full((len(pts), len(BLENDSHAPE_NAMES)), np.nan)
    if ok.any():
        out[ok] = head(pts[ok].astype(np.float32))[0]
    return out

