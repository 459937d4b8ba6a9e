"""Footage of a face with known weights: a blendshape face rendered performing a take (ground truth for
face landmarks, ``docs/accuracy.md``).

The face (a neutral, its polygons and shape deltas, facecap axes: metres, Z up, looking down -Y) gets
what a camera needs to find a face: skin, darker brows and redder lips painted by position, an eyeball
behind each eye opening (white, a brown iris, a pupil; turned by the gaze), a dark mouth cavity. The
openings are found from the mesh itself (its two upper boundary loops and the one below them). Lit by
Workbench's studio light turned to one side, with shadows; a perspective camera off the face's axis;
the head turning and moving; written by Blender's own FFmpeg (H.264 by default, lossy).

``render_face_clip`` renders in the current Blender process, into a scene of its own that it removes
afterwards; the command line runs it headless (``python -m facecap render-face``, or the benchmark).
"""

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...solvers.errors import FacecapError
from .render_state import mark_rendered

SKIN, LIPS, BROWS = (0.78, 0.58, 0.48), (0.62, 0.34, 0.34), (0.20, 0.14, 0.10)
SCLERA, IRIS, PUPIL, CAVITY = (0.92, 0.90, 0.88), (0.30, 0.20, 0.12), (0.02, 0.02, 0.02), (0.15, 0.04, 0.04)


@dataclass(frozen=True)
class Shot:
    """How a clip is filmed: resolution, rate, camera (azimuth and elevation in degrees from the face's
    front, distance in metres, lens mm), key light turn (degrees), codec and quality, antialiasing."""

    size: tuple = (640, 480)
    fps: float = 30.0
    azimuth: float = 20.0
    elevation: float = 8.0
    distance: float = 0.75
    lens: float = 50.0
    light: float = 40.0
    codec: str = "H264"  # Blender's FFmpeg codec: "H264", "MPEG4", "FFV1"
    quality: str = "MEDIUM"  # constant rate factor: "HIGH", "MEDIUM", "LOW", "VERYLOW", "LOWEST"
    antialiasing: str = "FXAA"  # Workbench's samples: "FXAA" (one render), "5", "8" (that many)


def _srgb_to_linear(c):
    c = np.asarray(c, dtype=np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def boundary_loops(polygons):
    """Vertex index sets of the mesh's boundary loops (edges used by one polygon), largest last."""
    count = {}
    for poly in polygons:
        for a, b in zip(poly, list(poly[1:]) + [poly[0]]):
            key = (min(a, b), max(a, b))
            count[key] = count.get(key, 0) + 1
    adjacent = {}
    for (a, b), n in count.items():
        if n == 1:
            adjacent.setdefault(a, []).append(b)
            adjacent.setdefault(b, []).append(a)
    seen, loops = set(), []
    for start in adjacent:
        if start in seen:
            continue
        stack, loop = [start], []
        seen.add(start)
        while stack:
            v = stack.pop()
            loop.append(v)
            for w in adjacent[v]:
                if w not in seen:
                    seen.add(w)
                    stack.append(w)
        loops.append(np.array(sorted(loop)))
    return sorted(loops, key=len)


@dataclass(frozen=True)
class Openings:
    """The face's eye openings (subject's right, left) and mouth opening, as vertex index arrays."""

    right_eye: np.ndarray
    left_eye: np.ndarray
    mouth: np.ndarray


def find_openings(neutral, polygons):
    """The two eye openings (the two highest inner boundary loops) and the mouth (the next one down)."""
    inner = boundary_loops(polygons)[:-1]  # the largest loop is the face's outer border
    if len(inner) < 3:
        raise FacecapError(f"the face mesh has {len(inner)} inner opening(s); rendering it needs two eyes and a mouth")
    centres = np.array([neutral[loop].mean(axis=0) for loop in inner])
    order = np.argsort(-centres[:, 2])  # Z up: highest first
    eyes = sorted(order[:2], key=lambda i: centres[i, 0])  # -X is the subject's right
    mouth = next(i for i in order[2:] if abs(centres[i, 0]) < 0.5 * abs(centres[eyes[1], 0] - centres[eyes[0], 0]))
    return Openings(inner[eyes[0]], inner[eyes[1]], inner[mouth])


def skin_colours(neutral, openings):
    """(V, 3) linear colours: skin, lips around the mouth opening, brows above each eye opening."""
    skin, lips, brows = (_srgb_to_linear(c) for c in (SKIN, LIPS, BROWS))
    cols = np.tile(skin, (len(neutral), 1))
    mouth = neutral[openings.mouth]
    width = np.ptp(mouth[:, 0])
    near = np.min(np.linalg.norm(neutral[:, None, [0, 2]] - mouth[None, :, [0, 2]], axis=2), axis=1)
    within = np.abs(neutral[:, 0] - mouth[:, 0].mean()) < 0.55 * width
    w = np.clip(1.0 - near / (0.22 * width), 0, 1) * within
    cols = cols * (1 - w[:, None]) + lips * w[:, None]
    for eye in (openings.right_eye, openings.left_eye):
        e = neutral[eye]
        c, half = e.mean(axis=0), np.ptp(e[:, 0]) / 2
        bx = (neutral[:, 0] - c[0] - 0.25 * half * np.sign(c[0])) / (2.0 * half)
        bz = (neutral[:, 2] - brow_ridge(neutral, c, half)(bx)) / (0.55 * half)  # on the ridge, as real brows sit
        front = neutral[:, 1] < c[1] + half
        w = np.sqrt(np.clip(1.0 - bx**2 - bz**2, 0, 1)) * front
        cols = cols * (1 - w[:, None]) + brows * w[:, None]
    return cols


def brow_ridge(neutral, centre, half):
    """The height (Z) of the brow ridge above an eye opening (``centre``, half its width) as a function of
    the brow's across coordinate (-1..1 over twice the width, outer end first on the subject's right):
    per column, the most forward skin between 0.5 and 3.5 half-widths above the eye; a quadratic through
    them (single vertices are noisy)."""
    across = (neutral[:, 0] - centre[0] - 0.25 * half * np.sign(centre[0])) / (2.0 * half)
    up = (neutral[:, 2] - centre[2]) / half
    above = (up > 0.5) & (up < 3.5) & (neutral[:, 1] < centre[1] + half)
    xs, zs = [], []
    for x in np.linspace(-1.0, 1.0, 17):
        col = np.flatnonzero(above & (np.abs(across - x) < 0.08))
        if col.size:
            xs.append(x)
            zs.append(neutral[col[np.argmin(neutral[col, 1])], 2])  # -Y is forward
    if len(xs) < 3:  # no ridge to find: where brows usually are
        return lambda b: centre[2] + 2.1 * half - 0.35 * half * b**2
    return np.poly1d(np.polyfit(xs, zs, 2))


def eyeball_geometry(neutral, eye):
    """(centre (3,), radius) of the eyeball behind an eye opening (scaled by the opening's width)."""
    e = neutral[eye]
    width = np.ptp(e[:, 0])
    centre = e.mean(axis=0) + np.array([0.0, 0.32 * width, 0.0])  # behind the opening (+Y is into the head)
    return centre, 0.41 * width


def _colour_attribute(mesh, colours):
    attr = mesh.color_attributes.new("FaceCap Colour", "FLOAT_COLOR", "POINT")
    rgba = np.c_[colours, np.ones(len(colours))].astype(np.float32)
    attr.data.foreach_set("color", rgba.ravel())
    mesh.color_attributes.active_color = attr


def _sphere(name, colour_of, segments=(48, 32)):
    """A unit UV sphere mesh whose vertex colours come from ``colour_of(unit directions (N, 3))``."""
    import bmesh  # bmesh: only with Blender
    import bpy  # bpy: Blender starts on first import

    bm = bmesh.new()
    bmesh.ops.create_uvsphere(bm, u_segments=segments[0], v_segments=segments[1], radius=1.0)
    mesh = bpy.data.meshes.new(name)
    bm.to_mesh(mesh)
    bm.free()
    co = np.empty(len(mesh.vertices) * 3)
    mesh.vertices.foreach_get("co", co)
    _colour_attribute(mesh, colour_of(co.reshape(-1, 3)))
    mesh.polygons.foreach_set("use_smooth", np.ones(len(mesh.polygons), bool))
    return mesh


def _eye_colours(dirs):
    angle = np.degrees(np.arccos(np.clip(-dirs[:, 1], -1, 1)))  # from the eye's front (-Y)
    sclera, iris, pupil = (_srgb_to_linear(c) for c in (SCLERA, IRIS, PUPIL))
    return np.where(angle[:, None] < 10, pupil, np.where(angle[:, None] < 24, iris, sclera))


class _Set:
    """The clip's scene: face with shape keys, eyeballs, mouth cavity, camera, light; removed on close."""

    def __init__(self, neutral, polygons, deltas, shot):
        import bpy  # bpy: Blender starts on first import

        self.scene = scene = bpy.data.scenes.new("FaceCap Face Footage")
        self.data = []
        openings = find_openings(neutral, polygons)
        self.head = head = bpy.data.objects.new("FaceCap Head", None)  # turns the face, eyes and mouth together
        scene.collection.objects.link(head)
        mesh = bpy.data.meshes.new("FaceCap Face")
        mesh.from_pydata(neutral.tolist(), [], [list(map(int, p)) for p in polygons])
        mesh.polygons.foreach_set("use_smooth", np.ones(len(mesh.polygons), bool))
        _colour_attribute(mesh, skin_colours(neutral, openings))
        self.face = face = bpy.data.objects.new("FaceCap Face", mesh)
        face.shape_key_add(name="Basis")
        self.keys = []
        for k, delta in enumerate(deltas):
            key = face.shape_key_add(name=f"shape{k}")
            key.data.foreach_set("co", (neutral + delta).astype(np.float32).ravel())
            key.slider_min, key.slider_max = -1.0, 2.0
            self.keys.append(key)
        self.eyes = []
        eye_mesh = _sphere("FaceCap Eye", _eye_colours)
        for eye in (openings.right_eye, openings.left_eye):
            centre, radius = eyeball_geometry(neutral, eye)
            obj = bpy.data.objects.new("FaceCap Eye", eye_mesh)
            obj.location, obj.scale = tuple(centre), (radius,) * 3
            obj.rotation_mode = "ZXY"
            self.eyes.append(obj)
        cavity = bpy.data.objects.new("FaceCap Mouth", _sphere("FaceCap Mouth", lambda d: np.tile(
            _srgb_to_linear(CAVITY), (len(d), 1)), (24, 16)))
        m = neutral[openings.mouth]
        width = np.ptp(m[:, 0])
        cavity.location = tuple(m.mean(axis=0) + np.array([0.0, 0.65 * width, -0.3 * width]))
        cavity.scale = (0.6 * width, 0.55 * width, 0.75 * width)  # dark behind the lips however wide the jaw opens
        for obj in [face, *self.eyes, cavity]:
            obj.parent = head
            scene.collection.objects.link(obj)
        self.data += [mesh, eye_mesh, cavity.data]
        self._camera(scene, neutral, shot)
        self._look(scene, shot)

    def _camera(self, scene, neutral, shot):
        import bpy  # bpy: Blender starts on first import
        import mathutils  # mathutils: only with Blender

        cam = bpy.data.objects.new("FaceCap Camera", bpy.data.cameras.new("FaceCap Camera"))
        cam.data.lens = shot.lens
        scene.collection.objects.link(cam)
        scene.camera = cam
        target = mathutils.Vector(tuple(neutral.mean(axis=0)))
        az, el = math.radians(shot.azimuth), math.radians(shot.elevation)
        offset = mathutils.Vector((math.sin(az) * math.cos(el), -math.cos(az) * math.cos(el), math.sin(el)))
        cam.location = target + offset * shot.distance
        cam.rotation_euler = (target - cam.location).to_track_quat("-Z", "Y").to_euler()
        self.data.append(cam.data)

    @staticmethod
    def _look(scene, shot):
        import bpy  # bpy: Blender starts on first import

        render = scene.render
        render.engine = "BLENDER_WORKBENCH"
        render.resolution_x, render.resolution_y = (int(v) for v in shot.size)
        render.resolution_percentage = 100
        render.fps, render.fps_base = int(round(shot.fps)), int(round(shot.fps)) / shot.fps
        shading = scene.display.shading
        shading.light, shading.color_type = "STUDIO", "VERTEX"
        shading.show_shadows, shading.shadow_intensity = True, 0.6
        shading.show_specular_highlight = True
        shading.studiolight_rotate_z = math.radians(shot.light)
        scene.display.render_aa = shot.antialiasing
        scene.view_settings.view_transform = "Standard"
        scene.world = world = bpy.data.worlds.new("FaceCap Face Footage")
        world.color = (0.05, 0.06, 0.08)
        settings = render.image_settings
        if hasattr(settings, "media_type"):  # Blender 5.0: video is a media type of its own
            settings.media_type = "VIDEO"
        settings.file_format = "FFMPEG"
        render.ffmpeg.format = "MKV" if shot.codec == "FFV1" else "MPEG4"
        render.ffmpeg.codec = shot.codec
        if shot.codec == "H264":
            render.ffmpeg.constant_rate_factor = shot.quality
        render.ffmpeg.gopsize = int(round(shot.fps))

    def pose(self, weights, head, gaze):
        """One frame: shape weights (K,), head (6,) yaw/pitch/roll radians + shift metres, gaze (2, 2)."""
        for key, w in zip(self.keys, weights):
            key.value = float(w)
        yaw, pitch, roll = head[:3]
        self.head.rotation_mode = "ZXY"
        self.head.rotation_euler = (pitch, roll, yaw)
        self.head.location = tuple(head[3:6])
        for eye, (eye_yaw, eye_pitch) in zip(self.eyes, gaze):
            eye.rotation_euler = (eye_pitch, 0.0, eye_yaw)

    def close(self):
        import bpy  # bpy: Blender starts on first import

        for obj in list(self.scene.collection.objects):
            bpy.data.objects.remove(obj)
        bpy.data.worlds.remove(self.scene.world)
        bpy.data.scenes.remove(self.scene)
        for block in self.data:
            for collection in (bpy.data.meshes, bpy.data.cameras):
                if block in collection.values():
                    collection.remove(block)


def render_face_clip(path, neutral, polygons, deltas, weights, *, head=None, gaze=None, shot=Shot()):
    """Render ``weights`` (F, K) of a face to a video file; returns its path.

    Parameters
    ----------
    neutral : (V, 3) metres, Z up, the face looking down -Y
    polygons : sequence of vertex index sequences
    deltas : (K, V, 3) shape deltas
    head : (F, 6) yaw, pitch, roll (radians) and shift (metres) of the head, optional
    gaze : (F, 2, 2) yaw, pitch of the subject's right and left eye (radians), optional
    shot : Shot
    """
    import bpy  # bpy: Blender starts on first import

    weights = np.asarray(weights, dtype=np.float64)
    F = len(weights)
    head = np.zeros((F, 6)) if head is None else np.asarray(head, dtype=np.float64)
    gaze = np.zeros((F, 2, 2)) if gaze is None else np.asarray(gaze, dtype=np.float64)
    stage = _Set(np.asarray(neutral, np.float64), polygons, np.asarray(deltas, np.float64), shot)
    scene = stage.scene
    window = bpy.context.window
    previous = window.scene if window is not None else None

    def pose(frame_scene, *_):
        if frame_scene == scene:
            i = min(max(frame_scene.frame_current - 1, 0), F - 1)
            stage.pose(weights[i], head[i], gaze[i])

    scene.frame_start, scene.frame_end = 1, F
    path = Path(path)
    scene.render.filepath = str(path)
    scene.render.use_file_extension = False
    bpy.app.handlers.frame_change_pre.append(pose)
    try:
        if window is not None:
            window.scene = scene
        with bpy.context.temp_override(scene=scene):
            mark_rendered()  # a review page forked from here could not render
            bpy.ops.render.render(animation=True, scene=scene.name)
    finally:
        bpy.app.handlers.frame_change_pre.remove(pose)
        if window is not None and previous is not None:
            window.scene = previous
        stage.close()
    if not path.is_file():
        raise FacecapError(f"{path}: Blender wrote no video (its FFmpeg lacks {shot.codec}?)")
    return path
