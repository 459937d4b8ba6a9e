"""Rendered footage of a real face with known weights, for the face-landmark tests (Blender's Workbench,
headless, H.264 through Blender's own FFmpeg).

The face is the ICT-FaceKit face region from ``shared/data/ict-facekit`` (``shared_data.ICT_FACEKIT``),
read as the landmark benchmark reads it, its expressions under ARKit names. A
clip is a rest hold, then blinks, a jaw opening, a smile, brows, and a look to the side, with the head
turning; ``ict_character`` writes another ICT identity as a character .blend (shape keys with the same
names) to retarget onto.
"""

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from shared_data import ICT_FACEKIT
from shared_data import reason as shared_data_reason

@dataclass(frozen=True, eq=False)
class Face:
    neutral: np.ndarray  # (V, 3) metres
    polygons: np.ndarray  # (Q, 4)
    shape_names: tuple
    deltas: np.ndarray  # (K, V, 3)
    identity: np.ndarray  # (I, V, 3)


def ict_face(path=ICT_FACEKIT / "ict_face.npz"):
    """The ICT face in the characters' axes with ARKit shape names (``landmark_bench.ict_arrays``)."""
    from facecap.facecap_addon.bench.landmark_bench import ict_arrays

    return Face(*ict_arrays(path))


def _bump(n, start, rise, hold, value=1.0):
    t = np.arange(n, dtype=np.float64)
    up = np.clip((t - start) / rise, 0, 1)
    down = np.clip((start + rise + hold + rise - t) / rise, 0, 1)
    return value * np.minimum(up, down)


#: Frames of the test clip: (shape(s), start, rise, hold, value).
EVENTS = ((("eyeBlinkLeft", "eyeBlinkRight"), 14, 2, 2, 1.0), (("jawOpen",), 22, 3, 3, 0.7),
          (("mouthSmileLeft", "mouthSmileRight"), 32, 3, 3, 0.8), (("browInnerUp",), 42, 3, 3, 0.8),
          (("eyeBlinkLeft", "eyeBlinkRight"), 50, 2, 2, 1.0))
REST = 12
N_FRAMES = 58
GAZE = (34, 3, 8, np.radians(20.0))  # start, rise, hold, yaw: both eyes look to the subject's left


def clip_weights(face, n=N_FRAMES):
    """(weights (n, K), head (n, 6), gaze (n, 2, 2)) of the test clip: rest, then :data:`EVENTS`."""
    weights = np.zeros((n, len(face.shape_names)))
    for shapes, start, rise, hold, value in EVENTS:
        for s in shapes:
            weights[:, face.shape_names.index(s)] = np.maximum(weights[:, face.shape_names.index(s)],
                                                               _bump(n, start, rise, hold, value))
    t = np.arange(n) / 30.0
    head = np.zeros((n, 6))
    after = np.clip((np.arange(n) - REST) / 6.0, 0, 1)
    head[:, 0] = np.radians(8.0) * np.sin(2 * np.pi * 0.4 * t) * after  # yaw
    head[:, 1] = np.radians(4.0) * np.sin(2 * np.pi * 0.3 * t + 1.0) * after  # pitch
    head[:, 2] = np.radians(3.0) * np.sin(2 * np.pi * 0.5 * t) * after  # roll
    gaze = np.zeros((n, 2, 2))
    start, rise, hold, yaw = GAZE
    gaze[:, :, 0] = _bump(n, start, rise, hold, yaw)[:, None]
    return weights, head, gaze


def render_test_clip(path, face, *, n=N_FRAMES):
    """Render the test clip of ``face`` to ``path`` (H.264); returns (path, weights, gaze)."""
    from facecap.facecap_addon.render.face_footage import Shot, render_face_clip
    from render_child import in_child

    weights, head, gaze = clip_weights(face, n)
    in_child(lambda: render_face_clip(path, face.neutral, face.polygons, face.deltas, weights, head=head, gaze=gaze,
                                      shot=Shot(distance=0.5)), label="the test clip")
    return Path(path), weights, gaze


def ict_character(path, face, *, seed=7, modes=20, name="ICT"):
    """Save another ICT identity (``modes`` identity coefficients drawn from ``seed``) as a .blend with one
    object ``name`` and a shape key per expression; returns the path."""
    from facecap.facecap_addon.bench.landmark_bench import ict_character as save

    return save(path, face.neutral, face.polygons, face.shape_names, face.deltas, face.identity, seed, modes, name)


def landmark_models():
    """The face-landmark model folder: found, or fetched once into the facecap cache (``python -m facecap
    landmark-models``: the locked mediapipe wheel from PyPI). Without them the test fails in CI
    (``FACECAP_CI=1``) and is skipped elsewhere, with the reason."""
    import os

    import pytest

    from facecap.solvers.errors import FacecapError
    from facecap.solvers.video.face_models import find_models

    try:
        return find_models()["mesh"].parent
    except FacecapError:
        pass
    try:
        from facecap.solvers.tools.landmark_models import install_models

        return install_models(log=lambda _m: None)
    except FacecapError as exc:
        reason = f"no face-landmark models and none could be fetched: {exc}"
        if os.environ.get("FACECAP_CI"):
            pytest.fail(f"CI prerequisite missing: {reason}", pytrace=False)
        pytest.skip(reason)


def ict_available():
    """Skip (fail in CI) when the ICT face is not in the shared data folder."""
    import os

    import pytest

    if not (ICT_FACEKIT / "ict_face.npz").is_file():
        reason = shared_data_reason(ICT_FACEKIT / "ict_face.npz")
        if os.environ.get("FACECAP_CI"):
            pytest.fail(f"CI prerequisite missing: {reason}", pytrace=False)
        pytest.skip(reason)
