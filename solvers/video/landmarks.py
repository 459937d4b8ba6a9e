"""Face landmarks from footage as a take: ``[tracking] method = "landmarks"`` (no markers, no seeds).

Every frame goes through MediaPipe's face mesh (``face_mesh``): 478 points named ``lm000``-``lm477``
by MediaPipe's own numbering (468 mesh points; ``lm468``-``lm472`` the subject's right iris, centre
first, ``lm473``-``lm477`` the left), in the footage's pixels with the model's relative depth
(``positions`` (F, 478, 3): x right, y down, z towards the camera negative, z in pixels like x).
Frames without a face are gaps (NaN) with confidence 0; the face is detected on the first frame
read and followed from frame to frame, detected again after a loss. The detector's jitter is
removed afterwards by :func:`~.landmark_filter.smooth_landmarks` (zero lag: the whole take is known).

:func:`metric_take` turns the pixels into a 3D take in metres (an adult face's eye-corner distance,
distance to the camera taken out frame by frame), which every marker strategy and the binding by
position accept; :data:`RIGID` are the points that move with the skull (stabilisation), and
:data:`REGIONS` group the points by the face region they follow.
"""

import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace

import numpy as np

from ..markers import MarkerSet
from .face_landmarker import BLENDSHAPE_NAMES, FaceLandmarker
from .face_mesh import N_MESH, N_POINTS, FaceMesh
from .landmark_filter import smooth_landmarks
from .landmarker_bundle import find_bundle
from .reading import Footage, Job

#: Names of the 478 points, MediaPipe's numbering.
NAMES = tuple(f"lm{i:03d}" for i in range(N_POINTS))


def _names(indices):
    return tuple(NAMES[i] for i in indices)


#: Points that move with the skull, not with expressions: upper forehead, the bridge and back of the
#: nose, the temples and the sides of the face at the ears (the default stabilisation set).
RIGID = _names((10, 109, 338, 67, 297, 168, 6, 197, 195, 5, 127, 356, 234, 454, 162, 389))
#: Which points follow which part of the face (documentation and per-region diagnostics).
REGIONS = {
    "brows": _names((70, 63, 105, 66, 107, 55, 65, 52, 53, 46, 300, 293, 334, 296, 336, 285, 295, 282, 283, 276)),
    "lids": _names((159, 145, 158, 153, 160, 144, 161, 163, 386, 374, 385, 380, 387, 373, 388, 390)),
    "gaze": _names(range(468, 478)),
    "cheeks_nose": _names((50, 101, 118, 117, 280, 330, 347, 346, 48, 278, 64, 294, 98, 327, 1, 2)),
    "jaw": _names((152, 148, 176, 377, 400, 149, 378, 136, 365, 172, 397)),
    "mouth": _names((61, 291, 0, 17, 13, 14, 37, 267, 84, 314, 40, 270, 91, 321, 78, 308, 81, 311, 178, 402,
                     82, 312, 87, 317)),
}
#: Frames the blendshape head scores at a time, beside the landmark model (on the eyes' thread)
BLENDSHAPE_CHUNK = 32
#: An adult's outer eye-corner distance (lm033 - lm263), metres: the scale of :func:`metric_take`.
EYE_CORNERS_M = 0.09


@dataclass(frozen=True, eq=False)
class LandmarkResult:
    """Face landmarks of a clip.

    ``markers``: MarkerSet (F, 478, 3) in source pixels (x, y, depth), NaN where no face was found;
    ``confidence`` (F,): the mesh model's face score (0 at gaps); ``detections``: frame numbers where
    the face was detected (not followed); ``raw``: the positions before temporal filtering;
    ``timings``: seconds spent reading, in the models, filtering; ``blendshapes`` (F, 52): the Face
    Landmarker's blendshape scores (``blendshape_names``, NaN at gaps), None with the older models;
    ``model``: which models found the points ("face landmarker" or "face mesh").
    """

    markers: MarkerSet
    confidence: np.ndarray
    detections: tuple
    raw: np.ndarray
    smoothing: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)
    blendshapes: np.ndarray = None
    blendshape_names: tuple = BLENDSHAPE_NAMES
    model: str = "face mesh"

    @property
    def found(self):
        """(F,) frames with a face."""
        return np.isfinite(self.markers.positions[:, 0, 0])

    def summary(self):
        f = self.found
        gaps = int((~f).sum())
        return (f"face landmarks ({self.markers.n_markers} points) in {int(f.sum())} of {len(f)} frames"
                + (f", {gaps} frame(s) without a face left as gaps" if gaps else "")
                + f", mean confidence {self.confidence[f].mean() if f.any() else 0:.2f}, "
                f"{len(self.detections)} detection(s)")

    def report(self):
        """JSON-ready summary for a take's report."""
        return {"method": "landmarks", "model": self.model, "points": self.markers.n_markers, "frames": int(len(self.found)),
                "frames_with_face": int(self.found.sum()), "detections": list(self.detections),
                "mean_confidence": round(float(self.confidence[self.found].mean()) if self.found.any() else 0.0, 4),
                "smoothing": self.smoothing, "timings_s": {k: round(v, 3) for k, v in self.timings.items()}}


def track_landmarks(footage, *, models=None, smoothing=True, iris=True, bundle="auto", progress=None):
    """Face landmarks of every frame of ``footage`` (a :class:`~.reading.Footage` or a path).

    Parameters
    ----------
    models : folder of the three older model files, optional (default: found as ``face_models`` says)
    bundle : "auto", a path, or None
        The Face Landmarker bundle (``landmarker_bundle``): "auto" uses it when it is installed (else the
        older models), a path uses that file, None the older models.
    smoothing : bool or dict
        Temporal filtering of the detector's jitter (keyword options of
        :func:`~.landmark_filter.smooth_landmarks`), or False for the raw points.
    iris : bool
        Run the iris model of the older models (eyelids and gaze; about a third of their time).
    progress : callable(done, total) -> bool or None; False cancels (:class:`~.reading.Cancelled`)

    Returns
    -------
    LandmarkResult
    """
    return track_landmarks_job(footage, models=models, smoothing=smoothing, iris=iris, bundle=bundle).run(progress)


def track_landmarks_job(footage, *, models=None, smoothing=True, iris=True, bundle="auto"):
    """:func:`track_landmarks` as a :class:`~.reading.Job` that advances a frame per step (models loaded here)."""
    if not isinstance(footage, Footage):
        footage = Footage(footage, color=True)
    path = find_bundle() if isinstance(bundle, str) and bundle == "auto" else \
        None if bundle is None else find_bundle(bundle)
    mesh = FaceLandmarker(path) if path is not None else FaceMesh(models=models, iris=iris)
    return Job(_landmark_steps(footage, mesh, smoothing), footage.info.n_frames, info=footage.info)


def _landmark_steps(footage, mesh, smoothing):
    """Generator: per frame the mesh on this thread, the eyes of the frame before on a second one
    (two cores: the iris model is the larger half of the work of the older models; the Face Landmarker
    has no second step, its blendshape head runs over the whole clip at the end)."""
    info = footage.info
    F = info.n_frames
    pos = np.full((F, N_POINTS, 3), np.nan)
    conf = np.zeros(F)
    detections = []
    t_model, t0 = 0.0, time.perf_counter()
    reader = iter(footage)
    pending = None
    landmarker = isinstance(mesh, FaceLandmarker)
    scores = np.full((F, len(BLENDSHAPE_NAMES)), np.nan) if landmarker else None
    chunks, done = [], 0  # the blendshape head on the second thread, BLENDSHAPE_CHUNK frames at a time

    def score(a, b):
        scores[a:b] = mesh.blendshapes(pos[a:b])

    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="facecap-eyes") as eyes:
        try:
            for i, (f, img) in enumerate(reader):
                t1 = time.perf_counter()
                face, rgb = mesh.follow(img)
                if pending is not None:
                    pending.result()  # the eyes of the frame before: at most one frame in flight
                pending = None
                if face.points is not None:
                    pos[i] = face.points  # filled in place by the eyes' thread
                    conf[i] = face.presence
                    if not landmarker:
                        pending = eyes.submit(mesh.finish, rgb, pos[i])
                    if face.detected:
                        detections.append(int(f))
                if landmarker and i + 1 - done >= BLENDSHAPE_CHUNK:
                    chunks.append(eyes.submit(score, done, i + 1))
                    done = i + 1
                t_model += time.perf_counter() - t1
                yield f
            if pending is not None:
                pending.result()
            if landmarker:
                t1 = time.perf_counter()
                score(done, F)
                for c in chunks:
                    c.result()
                t_model += time.perf_counter() - t1
        finally:
            reader.close()
    t_all = time.perf_counter() - t0
    raw = pos.copy()
    raw[..., :2] = (raw[..., :2] + 0.5) / info.scale - 0.5  # working -> source pixels
    raw[..., 2] /= info.scale
    options = {} if smoothing is True else dict(smoothing or {})
    t2 = time.perf_counter()
    out, used = (smooth_landmarks(raw, info.fps, **options), options) if smoothing is not False else (raw, None)
    timings = {"read": max(t_all - t_model, 0.0), "models": t_model, "filter": time.perf_counter() - t2}
    markers = MarkerSet(NAMES, np.asarray(info.frames, dtype=np.float64), out, fps=info.fps, units="px",
                        source=info.path)
    return LandmarkResult(markers, conf, tuple(detections), raw,
                          smoothing={"applied": used is not None, **(used or {})}, timings=timings,
                          blendshapes=scores, model="face landmarker" if scores is not None else "face mesh")


def metric_take(result, *, eye_corners_m=EYE_CORNERS_M, iris=True):
    """The landmarks as a 3D take in metres, in the characters' convention (Z up, the face looking down
    -Y, +X the subject's left: image x, the model's depth, image y up), each frame scaled so the rigid
    points keep their typical spread (the face's distance to the camera taken out) and the whole take so
    the outer eye corners are ``eye_corners_m`` apart. ``iris=False`` leaves the iris points out (they
    sit on the eyeballs, not on the skin a solve binds to)."""
    markers = result.markers if isinstance(result, LandmarkResult) else result
    if not iris:
        markers = markers.subset(NAMES[:N_MESH])
    p = markers.positions[..., [0, 2, 1]] * np.array([1.0, 1.0, -1.0])
    rigid = [markers.names.index(n) for n in RIGID]
    core = p[:, rigid]
    spread = np.sqrt(np.nanmean(np.sum((core - np.nanmean(core, axis=1, keepdims=True)) ** 2, axis=2), axis=1))
    typical = np.nanmedian(spread)
    eyes = np.linalg.norm(p[:, 33] - p[:, 263], axis=1) * typical / spread
    scale = eye_corners_m / np.nanmedian(eyes)
    per_frame = (scale * typical / spread)[:, None, None]
    return replace(markers, positions=p * per_frame, units="m")
