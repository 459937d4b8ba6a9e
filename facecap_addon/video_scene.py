"""Movie clips -> footage the video tracker reads, and seed points from the clip's own tracks."""

import re
from pathlib import Path

import bpy
import numpy as np

from ..solvers.errors import FacecapError


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



class ClipFlowSolving(_ClipJob):
    """Solve from Clip Flow in steps: dense flow of the movie clip over the face region (Scene.facecap.video)
    relative to the neutral ``frame``, flow-PCA features, the strategy learned from the Solve panel's
    Examples action (its keyed frames on the character), weights for every clip frame. Nothing in the
    scene changes until :meth:`write` keys the solve layer (a cancelled run leaves the scene as it was).
    """

    what = "Solve from clip flow"
    label = "Flow of"

    def __init__(self, scene, clip, frame):
        from dataclasses import replace

        from ..solvers.video import Footage
        from ..solvers.video.flow_solve import FlowSolveSettings, retarget_flow_job
        from . import take

        settings, video = scene.facecap, scene.facecap.video
        if settings.target is None:
            raise FacecapError("choose the character (Target) first")
        if settings.examples_action is None:
            raise FacecapError("choose the Examples action in the Solve panel: the character keyed at the clip "
                               "frames you posed")
        examples = take.examples_from_action(settings.examples_action, settings.target)
        character = take.character_target(settings.target)
        rsettings = replace(take.retarget_settings(settings), strategy=video.flow_strategy)
        source, offset = clip_footage(clip)
        footage = Footage(source, frame_offset=offset, fps=clip.fps or scene.render.fps / scene.render.fps_base)
        region, stable = tuple(video.region), tuple(video.stable_region)
        flow = FlowSolveSettings(method=video.flow_method, reference=int(frame),
                                 region=region if region[2] * region[3] > 0 else None,
                                 stable_region=(stable,) if stable[2] * stable[3] > 0 else (),
                                 grid_step=video.flow_grid_step or None, n_components=video.flow_components)
        self.clip_name, self.settings = clip.name, settings
        self.job = retarget_flow_job(footage, character, examples, settings=rsettings, flow=flow)

    def write(self):
        """Key the finished solve (per-shape controls applied) as the character's solve layer; returns
        (action, the keyed RetargetResult)."""
        from .tuning_scene import key_solve, with_controls

        result = with_controls(self.settings, self.result)
        return key_solve(self.settings, result), result


def camera_from_scene(scene, name=None, *, object_matrix=None, resolution=None):
    """``solvers.camera.Camera`` of the scene camera (or the camera object ``name``).

    ``object_matrix`` (a character's ``matrix_world``) makes the camera see that object's local
    coordinates, where its bound points and shape deltas live. ``resolution`` (width, height) gives
    pixels of footage whose size differs from the render resolution (same aspect expected).
    """
    from ..solvers.character.camera import Camera

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
    """What ``solvers.pipeline.markers_2d`` projects a 2D take's character through: ``"front"`` or the
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


# -- flow-PCA features: solving footage without markers -------------------------------------------
def run_flow_retarget(config, *, quiet=False):
    """``run_retarget`` for a ``[source] video`` take: flow-PCA features of the footage, the
    ``[solve] strategy`` (linear / rbf / pca) learned from ``[examples] weights`` posed at footage
    frames; keys the solve layer and writes the same outputs. Returns (RetargetResult, outputs).

    The flow shows progress on stderr; Ctrl-C stops it between two frames with
    :class:`~facecap.solvers.video.Cancelled` and nothing written (the CLI exits 130).
    """
    import sys
    import time

    from ..solvers.config.strategies import load_strategy_inputs
    from ..solvers.video.cli import _Progress, sigint_cancels
    from ..solvers.video.flow_config import check_against_footage
    from ..solvers.video.flow_solve import retarget_flow_job
    from ..solvers.video.reading import Footage
    from .cli import key_and_write, open_target
    from .take import character_target
    from .tune_cli import finish_solve, prepare_solve

    def say(message):
        if not quiet:
            print(f"facecap: {message}", file=sys.stderr, flush=True)

    video, timings, t0 = config.video, {}, time.perf_counter()
    say(f"[1/5] reading footage {video.path}")
    footage = Footage(video.path, **video.footage)
    info = footage.info
    check_against_footage(config.path, video, info)
    inputs = load_strategy_inputs(config)
    timings["read"] = time.perf_counter() - t0

    t1 = time.perf_counter()
    obj = open_target(config, say)
    character, inputs, settings, tuning_info = prepare_solve(config, character_target(obj), inputs)
    timings["load_character"] = time.perf_counter() - t1

    job = retarget_flow_job(footage, character, inputs.examples, settings=settings, flow=video.flow)
    say(f"[3/5] {video.flow.method} flow over {info.n_frames} frames ({info.work_width}x{info.work_height}), "
        f"solving {len(character.names)} shapes (strategy: {settings.strategy}, "
        f"{len(inputs.examples.frames)} posed frames)")
    shown = None if quiet else _Progress(sys.stderr, f"flow ({video.flow.method})")
    with sigint_cancels() as stop:
        def progress(done, total):
            if shown is not None:
                shown(done, total)
            return not stop.is_set()

        try:
            result = job.run(progress)
        finally:
            if shown is not None:
                shown.close_line()
    result = finish_solve(config, result, info.fps)

    source = {"video_file": video.path,
              "source": {"format": "video", "kind": info.kind, "fps": info.fps, "width": info.width,
                         "height": info.height, "scale": info.scale, "frames": [info.frames[0], info.frames[-1]],
                         "count": info.n_frames},
              "flow": result.info["flow"], "examples_file": str(config.examples_weights_path), "cleaning": []}
    outputs = key_and_write(config, obj, result, outputs={}, timings=timings, t0=t0, notes=list(inputs.notes),
                            say=say, report_fields={**source, **tuning_info})
    return result, outputs
