"""MediaPipe's Face Landmarker bundle (``face_landmarker.task``, Apache-2.0): where it is, and its models.

The bundle is an uncompressed zip of a face detector, the 478-point landmark model (468 mesh points and
the irises, with depth) and the blendshape head (52 ARKit-named scores from 146 of the landmarks). It is
not shipped: ``python -m facecap landmark-models fetch`` (or *Download Face Models* in the Video panel)
downloads it once from MediaPipe's address into the facecap cache and checks its SHA-256, the file the
figures of docs/video.md were measured with. Without it the older face-mesh models of the locked
mediapipe wheel (``face_models``) are used, and a landmark take has no blendshape scores.

Looked up in this order: the ``path`` given (``[tracking] bundle``), ``$FACECAP_FACE_LANDMARKER``, the
facecap cache (``<cache>/models/face_landmarker.task``). Every copy is hash-checked before it is used.
"""

import os
import zipfile
from pathlib import Path

from ..errors import FacecapError
from ..io.files import file_sha256
from .face_models import cache_models_dir

BUNDLE_FILE = "face_landmarker.task"
BUNDLE_URL = ("https://storage.googleapis.com/mediapipe-models/face_landmarker/face_landmarker/float16/1/"
              + BUNDLE_FILE)
BUNDLE_SHA256 = "64184e229b263107bc2b804c6625db1341ff2bb731874b0bcc2fe6544e0bc9ff"
BUNDLE_SIZE = 3_758_596
ENVIRONMENT = "FACECAP_FACE_LANDMARKER"
#: role -> member of the bundle
MEMBERS = {"detector": "face_detector.tflite", "landmarks": "face_landmarks_detector.tflite",
           "blendshapes": "face_blendshapes.tflite"}
FETCH_HINT = "`python -m facecap landmark-models fetch` (or Download Face Models in the Video panel)"


def bundle_path():
    """Where ``fetch`` puts the bundle: ``<facecap cache>/models/face_landmarker.task``."""
    return cache_models_dir() / BUNDLE_FILE


def find_bundle(path=None):
    """The bundle's path: ``path`` if given (it must exist), else ``$FACECAP_FACE_LANDMARKER``, else the
    cache's copy; None when there is none (the older models are used then)."""
    if path is not None:
        path = Path(path).expanduser()
        if not path.is_file():
            raise FacecapError(f"{path}: no such file (the Face Landmarker bundle, {BUNDLE_FILE}; get it with "
                               f"{FETCH_HINT})")
        return path
    env = os.environ.get(ENVIRONMENT)
    if env:
        found = Path(env).expanduser()
        if not found.is_file():
            raise FacecapError(f"${ENVIRONMENT} names {found}, which is not a file (the Face Landmarker bundle)")
        return found
    cached = bundle_path()
    return cached if cached.is_file() else None


def check_bundle(path):
    """Raise unless ``path`` is the bundle facecap knows (size, then SHA-256)."""
    path = Path(path)
    size = path.stat().st_size
    if size != BUNDLE_SIZE or file_sha256(path) != BUNDLE_SHA256:
        raise FacecapError(f"{path}: not the Face Landmarker bundle facecap was measured with ({BUNDLE_SIZE:,} "
                           f"bytes, SHA-256 {BUNDLE_SHA256[:16]}...; this file has {size:,} bytes); download it "
                           f"again with {FETCH_HINT}")


def read_bundle(path):
    """{role: bytes} of the three models in the bundle at ``path`` (hash-checked first)."""
    path = Path(path)
    check_bundle(path)
    try:
        with zipfile.ZipFile(path) as z:
            return {role: z.read(member) for role, member in MEMBERS.items()}
    except (zipfile.BadZipFile, KeyError) as exc:  # unreachable for the known digest; a guard all the same
        raise FacecapError(f"{path}: the Face Landmarker bundle cannot be read ({exc})") from None
