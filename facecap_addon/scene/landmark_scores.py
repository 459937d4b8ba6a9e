"""What a landmark take keeps in the .blend (on its collection) besides its skin landmarks, read back for a solve:
the Face Landmarker's blendshape scores, and the eyes' points (irises, corners, lids) whose gaze and lid gap hold the
character's eye-look, blink and wide shapes through the solve as the headless take does (``hold_gaze``)."""

import numpy as np

from ...solvers.video.gaze import EYES, gaze_locks

#: The landmarks the gaze and lid locks read (``gaze.EYES``: iris, corners and lids of each eye).
EYE_LANDMARKS = tuple(sorted({i for eye in EYES for i in eye[:5]}))
#: Stands for "no face on this frame" in the kept eye points (ID properties hold no NaN).
NO_POINT = -1e9


def store_scores(coll, found):
    """Keep a landmark take's blendshape scores (LandmarkResult ``found``) on its collection: the .blend holds what
    a re-solve needs (-1 where no face was found: ID properties hold no NaN)."""
    if found.blendshapes is None:
        return
    coll["facecap_blendshapes"] = np.where(np.isfinite(found.blendshapes), found.blendshapes, -1.0).ravel().tolist()
    coll["facecap_blendshape_names"] = list(found.blendshape_names)
    coll["facecap_blendshape_frames"] = [float(f) for f in found.markers.frames]


def scores_from_collection(coll, frames):
    """(F, S) scores of the collection's take at ``frames`` (NaN where it has none) and their names, or None."""
    if coll is None or "facecap_blendshapes" not in coll:
        return None
    names = tuple(str(n) for n in coll["facecap_blendshape_names"])
    kept = np.asarray(coll["facecap_blendshape_frames"], dtype=np.float64)
    values = np.asarray(coll["facecap_blendshapes"], dtype=np.float64).reshape(len(kept), len(names))
    values[values < 0] = np.nan
    return _at_frames(kept, values, frames), names


def _at_frames(kept, values, frames):
    """``values`` (one row per frame of ``kept``) at ``frames``: NaN rows where the take kept nothing."""
    frames = np.asarray(frames, dtype=np.float64)
    out = np.full((len(frames),) + values.shape[1:], np.nan)
    at = np.searchsorted(kept, frames)
    hit = (at < len(kept)) & (kept[np.minimum(at, len(kept) - 1)] == frames)
    out[hit] = values[at[hit]]
    return out


def store_eye_points(coll, found):
    """Keep the image positions of a landmark take's eye points (LandmarkResult ``found``, :data:`EYE_LANDMARKS`)
    on its collection, when the take tracked the irises."""
    positions = found.markers.positions
    if positions.shape[1] <= max(EYE_LANDMARKS):
        return
    points = positions[:, EYE_LANDMARKS, :2]
    coll["facecap_eye_points"] = np.where(np.isfinite(points), points, NO_POINT).ravel().tolist()
    coll["facecap_eye_frames"] = [float(f) for f in found.markers.frames]


def keeps_landmark_extras(coll):
    """True when the collection's take is a landmark take keeping scores or eye points (a solve reads them)."""
    return coll is not None and ("facecap_blendshapes" in coll or "facecap_eye_points" in coll)


def landmark_eyes_kept(coll):
    """False for a landmark take (its collection keeps scores) tracked before its eye points were kept as well."""
    return coll is None or "facecap_blendshapes" not in coll or "facecap_eye_points" in coll


def eye_locks(coll, frames, neutral, shape_names):
    """Per-frame locks ``((shape, (F,) weights), ...)`` holding the character's eye-look shapes at the irises'
    gaze and its blink and wide shapes at the lids' gap (``gaze.gaze_locks``, relative to the ``neutral``
    indices of ``frames``), from the eye points the collection's take keeps; () when it keeps none."""
    if coll is None or "facecap_eye_points" not in coll:
        return ()
    kept = np.asarray(coll["facecap_eye_frames"], dtype=np.float64)
    values = np.asarray(coll["facecap_eye_points"], dtype=np.float64).reshape(len(kept), len(EYE_LANDMARKS), 2)
    values[values <= NO_POINT / 2] = np.nan
    positions = np.full((len(frames), max(EYE_LANDMARKS) + 1, 2), np.nan)  # gaze_locks reads landmarks by index
    positions[:, EYE_LANDMARKS] = _at_frames(kept, values, frames)
    return gaze_locks(tuple(shape_names), positions, neutral)
