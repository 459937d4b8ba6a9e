"""Movie clips -> footage the video tracker reads, and seed points from the clip's own tracks."""

import re
from pathlib import Path

import bpy
import numpy as np

from ...solvers.errors import FacecapError
from ...solvers.solve import solve_job
from ...solvers.video.flow import track_with_flow_job
from ...solvers.video.flow_solve import FlowSolveSettings
from ...solvers.video.landmarks import RIGID, metric_take, track_landmarks_job
from ...solvers.video.reading import Footage
from ...solvers.video.tracking import track_points_job
from .scene_solve import key_solve, request_from_scene


def clip_footage(clip):
    """(source, frame_offset) for solvers.video.Footage so that its frame numbers are scene frames.

    Footage numbers frames from 1 (the first frame of the video, the first file of a sequence);
    Blender shows a movie's first frame, or the sequence file named in ``clip.filepath``, at the
    scene frame ``clip.frame_start``.
    """
    path = Path(bpy.path.abspath(clip.filepath))
    if clip.source == "SEQUENCE":
        match = re.search(r"(\d+)(\.[^.]+)$", path.name)
        if not match:
            raise FacecapError(f"movie clip '{clip.name}': cannot find the frame number in '{path.name}'")
        shown = int(match.group(1))
        pattern = str(path.parent / (path.name[: match.start(1)] + "*" + match.group(2)))
        numbers = [int(m.group(1)) for p in path.parent.glob(path.name[: match.start(1)] + "*" + match.group(2))
                   if (m := re.search(r"(\d+)(\.[^.]+)$", p.name))]
        first = min(numbers, default=shown)  # Footage's frame 1
        return pattern, clip.frame_start - 1 - (shown - first)
    return str(path), clip.frame_start - 1


def clip_seeds(clip, frame):
    """Names and pixel positions (origin top-left) of the clip's enabled track markers at ``frame``."""
    width, height = clip.size
    names, points = [], []
    for track in clip.tracking.objects.active.tracks:
        marker = track.markers.find_frame(frame, exact=True)
        if marker is None or marker.mute:
            continue
        names.append(track.name)
        points.append((marker.co[0] * width, (1.0 - marker.co[1]) * height))
    return names, np.array(points, dtype=np.float64).reshape(-1, 2)


class _ClipJob:
    """A cancellable clip job (``self.job``) driven frame by frame by the modal operators."""

    what = ""  # for reports: "<what> cancelled at frame N"
    label = ""  # status bar: "<label> '<clip>': frame N (k/T)"

    @property
    def result(self):
        """The job's result once finished, else None."""
        return self.job.result

    def step(self, max_frames=1, *, seconds=None):
        """Advance up to ``max_frames`` more frames (or for ``seconds``); True when finished."""
        return self.job.step(max_frames, seconds=seconds)

    def run(self, progress=None):
        return self.job.run(progress)

    def cancel(self):
        self.job.cancel()

    def status(self):
        frame = "" if self.job.frame is None else f"frame {self.job.frame} "
        return f"{self.label} '{self.clip_name}': {frame}({self.job.done}/{self.job.total}) - Esc to cancel"


class ClipTracking(_ClipJob):
    """Tracking of a movie clip that advances in steps; nothing in the scene changes until the caller
    writes :attr:`result` (so a cancelled run leaves the scene as it was).

    Seeds are the clip's enabled track markers at ``frame`` or, when it has none there, up to
    ``max_points`` automatic features in ``region`` = (x, y, w, h) pixels. ``method``: "lk"
    (Lucas-Kanade) or a dense flow ("dis", "farneback", "tvl1") sampled at the seeds.
    """

    what = label = "Tracking"

    def __init__(self, scene, clip, frame, *, region=(0, 0, 0, 0), max_points=100, method="lk"):
        source, offset = clip_footage(clip)
        names, points = clip_seeds(clip, frame)
        if names:
            seeds = dict(points=points, names=names)
        elif region[2] * region[3] > 0:
            seeds = dict(region=tuple(region), max_points=max_points)
        else:
            raise FacecapError(f"movie clip '{clip.name}' has no enabled track markers at frame {frame}; "
                               "add markers or give a Region")
        fps = clip.fps or scene.render.fps / scene.render.fps_base
        self.clip_name = clip.name
        footage = Footage(source, frame_offset=offset, fps=fps)
        if method == "lk":
            self.job = track_points_job(footage, reference=frame, **seeds)
        else:  # dense flow (DIS, Farneback, TV-L1) sampled at the seeds
            self.job = track_with_flow_job(footage, reference=frame, method=method, **seeds)



class ClipLandmarks(_ClipJob):
    """Track Face Landmarks in steps: the movie clip's face landmarks (no markers, no seeds), as a 3D take in
    metres once finished (:attr:`take`); nothing in the scene changes until the operator adds it."""

    what = "Face landmarks"
    label = "Face landmarks in"

    def __init__(self, scene, clip, *, smoothing=True):
        source, offset = clip_footage(clip)
        fps = clip.fps or scene.render.fps / scene.render.fps_base
        self.clip_name = clip.name
        self.job = track_landmarks_job(Footage(source, frame_offset=offset, fps=fps, color=True), smoothing=smoothing)

    @property
    def take(self):
        return metric_take(self.result, iris=False)  # the irises sit on the eyeballs, not on skin


def use_landmark_defaults(settings):
    """Set the sidebar up as a landmark take needs it: the head-rigid landmarks stable, the neutral
    detected, the binding by position found automatically, the human template not used unless a path
    names one (``flow_config.landmark_defaults``)."""
    rigid = set(RIGID)
    if settings.actor_template.strip() in ("", "auto"):
        settings.actor_template = "none"
    for item in settings.markers:
        item.stable = item.name in rigid
    settings.neutral_mode = "DETECT"
    settings.binding_mode = "nearest"


class ClipFlowSolving(_ClipJob):
    """Solve from Clip Flow in steps: dense flow of the movie clip over the face region (Scene.facecap.video)
    relative to the neutral ``frame``, flow-PCA features, the strategy learned from the Solve panel's
    Examples action (its keyed frames on the character), weights for every clip frame. Nothing in the
    scene changes until :meth:`write` keys the solve layer (a cancelled run leaves the scene as it was).
    """

    what = "Solve from clip flow"
    label = "Flow of"

    def __init__(self, scene, clip, frame):
        settings, video = scene.facecap, scene.facecap.video
        if settings.target is None:
            raise FacecapError("choose the character (Target) first")
        if settings.examples_action is None:
            raise FacecapError("choose the Examples action in the Solve panel: the character keyed at the clip "
                               "frames you posed")
        source, offset = clip_footage(clip)
        footage = Footage(source, frame_offset=offset, fps=clip.fps or scene.render.fps / scene.render.fps_base)
        region, stable = tuple(video.region), tuple(video.stable_region)
        flow = FlowSolveSettings(method=video.flow_method, reference=int(frame),
                                 region=region if region[2] * region[3] > 0 else None,
                                 stable_region=(stable,) if stable[2] * stable[3] > 0 else (),
                                 grid_step=video.flow_grid_step or None, n_components=video.flow_components)
        self.clip_name, self.settings = clip.name, settings
        self.job = solve_job(request_from_scene(settings, scene, footage=footage, flow=flow))

    def write(self):
        """Key the finished solve (per-shape controls applied) as the character's solve layer; returns
        (action, the keyed RetargetResult)."""

        return key_solve(self.settings, self.result), self.result
