"""Where the face-landmark models are, and loading them into OpenCV's DNN module.

The models are MediaPipe's face mesh (Apache-2.0): a face detector (``face_detection_short_range``,
128x128), the 468-point mesh with a relative depth (``face_landmark``, 192x192) and the iris and
eyelid refinement (``iris_landmark``, 64x64). Later MediaPipe releases dropped these files; they are
taken from the locked ``mediapipe`` 0.10.21 wheel (``wheels.lock.toml``, ``[[asset]]``), never
downloaded at run time. They run in OpenCV's DNN module, which the project already has (the same
outputs as the TensorFlow Lite runtime to 1e-4; docs/video.md).

Looked up in this order: the ``models`` argument, ``$FACECAP_LANDMARK_MODELS``, the folder beside
this module (the extension build puts them there), the ``models`` folder of the facecap cache
(written by ``python -m facecap landmark-models``), and an installed ``mediapipe`` 0.10 package.
"""

import importlib.util
import os
from pathlib import Path

from ..errors import FacecapError
from .reading import opencv

#: role -> file name (as in the mediapipe wheel)
MODEL_FILES = {"detector": "face_detection_short_range.tflite", "mesh": "face_landmark.tflite",
               "iris": "iris_landmark.tflite"}
#: where each file sits inside an installed mediapipe package
MEDIAPIPE_MEMBERS = {"detector": "modules/face_detection", "mesh": "modules/face_landmark",
                     "iris": "modules/iris_landmark"}
BUNDLED = Path(__file__).resolve().parent / "models"
ENVIRONMENT = "FACECAP_LANDMARK_MODELS"


class LandmarkModelsMissing(FacecapError):
    """The face-landmark models are not installed; the message says how to get them."""

    def __init__(self, looked):
        super().__init__(
            "face landmarks need MediaPipe's face-mesh models (" + ", ".join(MODEL_FILES.values()) + "), found "
            f"in none of: {'; '.join(looked)}. Outside Blender run `python -m facecap landmark-models` once "
            "(it takes them from the locked mediapipe 0.10.21 wheel on PyPI into the facecap cache); in Blender "
            "install the facecap extension zip, which bundles them")


def cache_models_dir():
    """``<facecap cache>/models`` (``$FACECAP_CACHE``, else ``~/.cache/facecap``)."""
    if os.environ.get("FACECAP_CACHE"):
        root = Path(os.environ["FACECAP_CACHE"])
    else:
        root = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "facecap"
    return root / "models"


def _mediapipe_dirs():
    spec = importlib.util.find_spec("mediapipe")  # found, never imported (its import is slow and heavy)
    roots = [Path(p) for p in (spec.submodule_search_locations or [])] if spec else []
    return [{role: root / sub / MODEL_FILES[role] for role, sub in MEDIAPIPE_MEMBERS.items()} for root in roots]


def find_models(models=None):
    """{role: Path} of the three model files, from the first place that has all of them.

    Raises
    ------
    LandmarkModelsMissing naming where it looked and what to install.
    """
    if models is not None:  # a folder the user named is the only place looked
        paths = {role: Path(models).expanduser() / name for role, name in MODEL_FILES.items()}
        missing = [p.name for p in paths.values() if not p.is_file()]
        if missing:
            raise FacecapError(f"{models}: no {', '.join(missing)} in this folder (the face-landmark models)")
        return paths
    candidates, looked = [], []
    for folder in (os.environ.get(ENVIRONMENT) or None, BUNDLED, cache_models_dir()):
        if folder is not None:
            folder = Path(folder).expanduser()
            candidates.append((str(folder), {role: folder / name for role, name in MODEL_FILES.items()}))
    mediapipe = _mediapipe_dirs()
    candidates += [(f"the installed mediapipe package ({paths['mesh'].parents[2]})", paths) for paths in mediapipe]
    for where, paths in candidates:
        if all(p.is_file() for p in paths.values()):
            return paths
        looked.append(where)
    raise LandmarkModelsMissing(looked + ([] if mediapipe else ["no mediapipe package"]))


def load_networks(models=None):
    """{role: cv2.dnn.Net} of the three models (one thread each: frames are the parallel unit)."""
    cv2 = opencv()
    nets = {}
    for role, path in find_models(models).items():
        try:
            net = cv2.dnn.readNetFromTFLite(str(path))
        except cv2.error as exc:
            raise FacecapError(f"{path}: cannot be loaded as a TensorFlow Lite model ({str(exc).strip()[-160:]})") \
                from None
        net.setPreferableBackend(cv2.dnn.DNN_BACKEND_OPENCV)
        net.setPreferableTarget(cv2.dnn.DNN_TARGET_CPU)
        nets[role] = net
    return nets
