"""Movie clips -> footage the video tracker reads, and seed points from the clip's own tracks."""

import re
from pathlib import Path

import bpy
import numpy as np

from ..solvers.errors import FacecapError


def clip_footage(clip):
    """(source, frame_offset) for solvers.video.Footage so that its frame numbers are scene frames.

    Videos number frames from 0 in the file; image sequences by the number in the file name. The
    clip starts at ``clip.frame_start`` in the scene.
    """
    path = Path(bpy.path.abspath(clip.filepath))
    if clip.source == "SEQUENCE":
        match = re.search(r"(\d+)(\.[^.]+)$", path.name)
        if not match:
            raise FacecapError(f"movie clip '{clip.name}': cannot find the frame number in '{path.name}'")
        first = int(match.group(1))
        pattern = str(path.parent / (path.name[: match.start(1)] + "*" + match.group(2)))
        return pattern, clip.frame_start - first
    return str(path), clip.frame_start


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


class ClipTracking:
    """Tracking of a movie clip that advances in steps; nothing in the scene changes until the caller
    writes :attr:`result` (so a cancelled run leaves the scene as it was).

    Seeds are the clip's enabled track markers at ``frame`` or, when it has none there, up to
    ``max_points`` automatic features in ``region`` = (x, y, w, h) pixels. ``method``: "lk"
    (Lucas-Kanade) or a dense flow ("dis", "farneback", "tvl1") sampled at the seeds.
    """

    def __init__(self, scene, clip, frame, *, region=(0, 0, 0, 0), max_points=100, method="lk"):
        from ..solvers.video import Footage
        from ..solvers.video.flow import track_with_flow_job
        from ..solvers.video.tracking import track_points_job

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

    @property
    def result(self):
        """The TrackResult once finished, else None."""
        return self.job.result

    def step(self, max_frames=1, *, seconds=None):
        """Track up to ``max_frames`` more frames (or for ``seconds``); True when finished."""
        return self.job.step(max_frames, seconds=seconds)

    def run(self, progress=None):
        return self.job.run(progress)

    def cancel(self):
        self.job.cancel()

    def status(self):
        """``"Tracking 'clip': frame N (k/T)"`` for the status bar."""
        frame = "" if self.job.frame is None else f"frame {self.job.frame} "
        return f"Tracking '{self.clip_name}': {frame}({self.job.done}/{self.job.total}) - Esc to cancel"


def camera_from_scene(scene, name=None, *, object_matrix=None, resolution=None):
    """``solvers.camera.Camera`` of the scene camera (or the camera object ``name``).

    ``object_matrix`` (a character's ``matrix_world``) makes the camera see that object's local
    coordinates, where its bound points and shape deltas live. ``resolution`` (width, height) gives
    pixels of footage whose size differs from the render resolution (same aspect expected).
    """
    from ..solvers.camera import Camera

    if name:
        obj = bpy.data.objects.get(name)
        if obj is None or obj.type != "CAMERA":
            raise FacecapError(f"'{name}' is not a camera object in this .blend")
    else:
        obj = scene.camera
        if obj is None:
            raise FacecapError(f"scene '{scene.name}' has no camera; set one or name it ([solve] camera)")
    cam, render = obj.data, scene.render
    pct = render.resolution_percentage / 100.0
    size = (int(render.resolution_x * pct), int(render.resolution_y * pct))
    if cam.type not in ("PERSP", "ORTHO"):
        raise FacecapError(f"camera '{obj.name}': {cam.type} cameras are not supported (perspective or orthographic)")
    model = Camera.from_blender(
        lens=cam.lens, sensor_width=cam.sensor_width, sensor_height=cam.sensor_height, sensor_fit=cam.sensor_fit,
        resolution=size, shift=(cam.shift_x, cam.shift_y), matrix_world=np.array(obj.matrix_world),
        pixel_aspect=(render.pixel_aspect_x, render.pixel_aspect_y), orthographic=cam.type == "ORTHO",
        ortho_scale=cam.ortho_scale,
    )
    if resolution is not None:
        w, h = (int(v) for v in resolution)
        if abs(w / h - size[0] / size[1]) > 1e-3:
            raise FacecapError(f"camera '{obj.name}': footage {w}x{h} and render {size[0]}x{size[1]} differ in aspect")
        s = w / size[0]
        model = Camera(model.fx * s, model.fy * s, model.cx * s, model.cy * s, w, h, model.world_to_camera,
                       model.orthographic)
    if object_matrix is not None:
        model = model.relative_to(np.array(object_matrix))
    return model


def projection_for(scene, character, projection="front", camera_name=None, *, resolution=None):
    """What ``solvers.pipeline_2d`` projects a 2D take's character through: ``"front"`` or the
    camera (``camera_name`` or the scene camera) seeing ``character``'s local coordinates.

    For the take config (``[solve] projection`` / ``camera``) and the sidebar (Scene.facecap.video).
    """
    if projection == "front":
        return "front"
    if projection != "camera":
        raise FacecapError(f"projection must be 'front' or 'camera'; got {projection!r}")
    return camera_from_scene(scene, camera_name or None, object_matrix=character.matrix_world, resolution=resolution)


def projection_from_sidebar(scene, character, *, resolution=None):
    """``projection_for`` with the sidebar's Scene.facecap.video settings."""
    video = scene.facecap.video
    camera = video.camera.name if video.camera is not None else None
    return projection_for(scene, character, video.projection, camera, resolution=resolution)
