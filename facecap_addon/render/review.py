"""The review page from Blender: the contact sheet rendered with Workbench, and the page of a headless
take (``[output] html``, ``retarget --html``) or of the sidebar's take (*Export Review Report*).

The renders use a copy of the character in a scene of their own (its shape keys set from the solved
weights, no animation, no deforming modifiers: the rest position the markers are bound in), removed
afterwards, so the user's scene is never touched. Headless on Linux they run in a forked child: a
machine without OpenGL (EGL) makes Blender abort, which then costs the contact sheet, not the run.
"""

import dataclasses
import faulthandler
import multiprocessing as mp
import os
import sys
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from ...solvers.engine.split import HeldInterrupts
from ...solvers.errors import ConfigError, FacecapError
from ...solvers.io.images import encode_png
from ...solvers.io.outputs import Output, check_outputs, user_path
from ...solvers.solve import solve
from ...solvers.tools.report import (
    ContactSheet,
    Review,
    Tile,
    marker_geometry,
    pick_frames,
    read_truth,
    write_review_page,
)
from . import render_state
from ..scene.scene_data import vertex_group_bindings

#: Tile height in pixels and width / height (a face is taller than wide).
TILE_HEIGHT, ASPECT = 280, 0.8
#: The view: the bound points' extent times this (room for the forehead, chin and ears).
MARGIN = 1.5
#: Seconds a forked render may take (then it is stopped, and tried again: ``RENDER_TRIES``);
#: the sample's nine tiles take 2-4 s with software OpenGL.
RENDER_TIMEOUT = 120.0
#: Forked children a contact sheet gets when they die or hang (a fork of a multi-threaded process can deadlock:
#: one did, once in CI on Python 3.13; a render that is only slow costs ``RENDER_TIMEOUT`` per try).
RENDER_TRIES = 2
#: Whether this process has rendered (has an OpenGL context), by any facecap render: see render_state.
_state = render_state.STATE


@dataclasses.dataclass(frozen=True)
class ReviewOptions:
    """How a headless run writes its review page (``run_take(config, review=...)``): ``plotly_js`` is
    "embed" or the path of a shared plotly.min.js (a batch's pages: ``shared_plotly_js``); ``render``
    the contact sheet. The known weights it overlays are the config's ``truth_path`` (``--truth``)."""

    plotly_js: object = "embed"
    render: bool = True


def _quiet(log):
    """Send this process's stdout and stderr (Blender's render log, Mesa's EGL notes) to the file descriptor
    ``log``: off the user's console, kept to say why should the process die."""
    os.dup2(log, 1)
    os.dup2(log, 2)


def _last_line(log):
    """The last line a dead child printed into the temporary file ``log`` (its reason), or ""."""
    log.seek(0, os.SEEK_END)
    log.seek(max(0, log.tell() - 4096))
    lines = [line.strip() for line in log.read().decode("utf-8", "replace").splitlines() if line.strip()]
    return lines[-1] if lines else ""


@contextmanager
def _camera(scene, name):
    import bpy  # bpy: Blender starts on first import

    cam = bpy.data.objects.new(name, bpy.data.cameras.new(name))
    cam.data.type = "ORTHO"
    scene.collection.objects.link(cam)
    scene.camera = cam
    try:
        yield cam
    finally:
        data = cam.data
        bpy.data.objects.remove(cam)
        bpy.data.cameras.remove(data)


class _Stage:
    """A scene of its own holding a copy of the character, lit and framed on ``points`` (local, (N, 3))
    seen from ``front`` (a world direction)."""

    def __init__(self, obj, points, front, tmp, height=TILE_HEIGHT):
        import bpy  # bpy: Blender starts on first import

        self.tmp = Path(tmp)
        self.scene = scene = bpy.data.scenes.new("FaceCap Review")
        self.face = face = obj.copy()
        face.data = obj.data.copy()  # the copy has its own shape keys
        face.animation_data_clear()
        if face.data.shape_keys is not None:
            face.data.shape_keys.animation_data_clear()
        face.parent = None
        face.matrix_world = obj.matrix_world.copy()
        for mod in list(face.modifiers):
            if mod.type != "SUBSURF":  # deforming modifiers would move the face off its bound points
                face.modifiers.remove(mod)
        face.constraints.clear()
        scene.collection.objects.link(face)
        render = scene.render
        render.engine = "BLENDER_WORKBENCH"
        render.resolution_x, render.resolution_y = int(round(height * ASPECT)), height
        render.resolution_percentage = 100
        render.film_transparent = False  # on the world's white: Blender writes the page's PNG itself
        render.image_settings.file_format = "PNG"
        render.image_settings.color_mode = "RGB"
        render.image_settings.compression = 60  # 2x smaller than the default 15 for 10 ms more per tile
        scene.world = self.world_data = bpy.data.worlds.new("FaceCap Review")
        self.world_data.color = (1.0, 1.0, 1.0)
        scene.view_settings.view_transform = "Standard"
        scene.display.shading.light, scene.display.shading.color_type = "STUDIO", "MATERIAL"
        scene.display.render_aa = "5"  # 5 samples: 40 % faster than 8, edges as smooth at this size
        self.world = np.array(obj.matrix_world, dtype=np.float64)
        self.front, self.points = front, np.asarray(points, dtype=np.float64)
        self.images = set(bpy.data.images)  # rendering adds "Render Result" if it is not there yet

    def frame(self, cam):
        """Point ``cam`` at the bound points from the face's front, framing them with a margin."""
        import mathutils  # mathutils: only with Blender

        pts = self.to_world(self.points)
        up = np.array([0.0, 0.0, 1.0]) - self.front * self.front[2]
        up = up / np.linalg.norm(up) if np.linalg.norm(up) > 1e-6 else np.array([0.0, 1.0, 0.0])
        right = np.cross(up, self.front)
        u, v = pts @ right, pts @ up
        centre = pts.mean(axis=0) + right * (0.5 * (u.max() + u.min()) - u.mean()) + up * (0.5 * (v.max() + v.min()) - v.mean())
        extent = max(np.ptp(v), np.ptp(u) / ASPECT) * MARGIN
        depth = float(np.ptp(pts @ self.front)) + extent
        cam.data.ortho_scale = extent
        cam.data.clip_start, cam.data.clip_end = depth * 1e-3, depth * 100.0
        cam.location = tuple(centre + self.front * depth * 4.0)
        look = mathutils.Vector(tuple(-self.front))
        cam.rotation_euler = look.to_track_quat("-Z", "Y").to_euler()
        if abs(np.dot(np.array(cam.matrix_world)[:3, 1], up)) < 0.5:  # track_quat keeps Y up: fine unless the face lies flat
            cam.rotation_euler = look.to_track_quat("-Z", "Z").to_euler()

    def to_world(self, points):
        return np.asarray(points, dtype=np.float64) @ self.world[:3, :3].T + self.world[:3, 3]

    def project(self, cam, points):
        """(N, 2) pixels (from the top left) of local-space ``points`` (N, 3) in ``cam``'s render."""
        from bpy_extras.object_utils import world_to_camera_view  # bpy_extras: only with Blender
        import mathutils  # mathutils: only with Blender

        self.scene.view_layers[0].update()
        w, h = self.scene.render.resolution_x, self.scene.render.resolution_y
        out = np.full((len(points), 2), np.nan)
        for i, p in enumerate(self.to_world(points)):
            if np.isfinite(p).all():
                x, y, _ = world_to_camera_view(self.scene, cam, mathutils.Vector(tuple(p)))
                out[i] = (x * w, (1.0 - y) * h)
        return out

    def pose(self, names, values):
        key = self.face.data.shape_keys
        if key is None:
            return
        blocks = key.key_blocks
        wanted = dict(zip(names, np.nan_to_num(values)))
        for block in blocks:
            if block != key.reference_key:
                block.value = float(wanted.get(block.name, 0.0))

    def render(self):
        """PNG bytes (RGB on white) and size of the current pose."""
        import bpy  # bpy: Blender starts on first import

        png = self.tmp / "tile.png"
        self.scene.render.filepath = str(png)
        bpy.ops.render.render(write_still=True, scene=self.scene.name)
        return png.read_bytes(), self.scene.render.resolution_x, self.scene.render.resolution_y

    def remove(self):
        import bpy  # bpy: Blender starts on first import

        mesh = self.face.data
        key = None if mesh.shape_keys is None else mesh.shape_keys.name
        bpy.data.objects.remove(self.face)
        bpy.data.meshes.remove(mesh)  # frees its shape keys with it (checked: none is left behind)
        left = bpy.data.shape_keys.get(key) if key is not None else None
        if left is not None and left.users == 0:
            bpy.data.batch_remove([left])
        bpy.data.scenes.remove(self.scene)
        bpy.data.worlds.remove(self.world_data)
        for image in set(bpy.data.images) - self.images:
            bpy.data.images.remove(image)


def _front(obj, names, world):
    """The face's front direction in world space: the mean normal of the vertices its markers' vertex groups
    hold (without them: Blender's front view, -Y)."""
    if not names:
        return np.array([0.0, -1.0, 0.0])
    normals = np.empty(len(obj.data.vertices) * 3)
    obj.data.vertices.foreach_get("normal", normals)
    normals = normals.reshape(-1, 3)
    bindings = vertex_group_bindings(obj, names)
    if not bindings:  # bound by position (no vertex groups): Blender's front view
        return np.array([0.0, -1.0, 0.0])
    n = np.sum([w @ normals[idx] for idx, w in bindings.values()], axis=0)
    n = world[:3, :3] @ n
    return n / np.linalg.norm(n) if np.linalg.norm(n) > 1e-9 else np.array([0.0, -1.0, 0.0])


def render_sheet(obj, result, geometry, picks, *, height=TILE_HEIGHT):
    """The contact sheet: ``obj`` posed at each pick (``pick_frames``) with, given ``geometry``
    (MarkerGeometry), the markers projected into the same view and a tile of the binding on the neutral.
    Returns ContactSheet."""
    t0 = time.perf_counter()
    _state["rendered_here"] = True  # in a forked child this marks the child only
    world = np.array(obj.matrix_world, dtype=np.float64)
    if geometry is not None:
        points, names = geometry.bound, geometry.names
    else:  # no markers on the character: frame the whole mesh
        points, names = np.array([tuple(c) for c in obj.bound_box], dtype=np.float64), ()
    with tempfile.TemporaryDirectory(prefix="facecap-review-") as tmp:
        stage = _Stage(obj, points, _front(obj, names, world), tmp, height)
        try:
            with _camera(stage.scene, "FaceCap Review Camera") as cam:
                stage.frame(cam)
                tiles = [_tile(stage, cam, result, geometry, row, kind, label) for row, kind, label in picks]
                binding = None
                if geometry is not None:
                    stage.pose((), ())
                    png, w, h = stage.render()
                    binding = Tile(float("nan"), "neutral: binding", "binding", png, w, h,
                                   stage.project(cam, geometry.actor_neutral), stage.project(cam, geometry.bound),
                                   geometry.binding_mm)
        finally:
            stage.remove()
    return ContactSheet(tuple(tiles), names, binding, time.perf_counter() - t0)


def _tile(stage, cam, result, geometry, row, kind, label):
    stage.pose(result.shape_names, result.weights[row])
    png, w, h = stage.render()
    if geometry is None:
        return Tile(float(result.frames[row]), label, kind, png, w, h)
    captured, model = geometry.captured([row])[0], geometry.model([row])[0]
    return Tile(float(result.frames[row]), label, kind, png, w, h, stage.project(cam, captured),
                stage.project(cam, model), np.linalg.norm(captured - model, axis=1) * 1e3)


def render_guarded(work, *, timeout=None):
    """``(work(), "")``, or ``(None, why)`` when rendering failed. Headless on Linux ``work`` runs in a
    forked child with its output kept off the console, so an abort (no OpenGL) cannot end the run; a child that
    dies or takes longer than ``timeout`` (default ``RENDER_TIMEOUT``) is tried once more (software OpenGL has
    aborted once in a long test run that had rendered fine before, a child has hung once; a machine without OpenGL
    fails both tries at once). In a Blender with a window, or a process that has rendered before, it runs here."""
    import bpy  # bpy: Blender starts on first import

    if not (bpy.app.background and sys.platform.startswith("linux")) or _state["rendered_here"]:
        try:
            return work(), ""
        except RuntimeError as exc:  # Blender's render errors
            return None, f"rendering failed ({exc})"
    timeout = RENDER_TIMEOUT if timeout is None else timeout
    failed, said = [], ""
    for _ in range(RENDER_TRIES):
        with tempfile.TemporaryFile() as log:
            outcome = _render_forked(work, timeout, log)
            if isinstance(outcome, tuple):
                return outcome
            failed.append(outcome)
            said = _last_line(log) or said
    said = f"; it printed last: {said[:300]}" if said else ""
    if all(f is None for f in failed):
        return None, f"rendering took longer than {timeout:.0f} s and was stopped ({len(failed)} tries{said})"
    exits = ", ".join("stopped" if f is None else str(f) for f in failed)
    return None, (f"Blender stopped while rendering ({len(failed)} tries, exit {exits}{said}); on a machine without "
                  "a GPU Workbench needs Mesa's EGL (libegl1, libgl1-mesa-dri)")


def _render_forked(work, timeout, log):
    """``render_guarded``'s forked child, its output into the file ``log``: (value, "") or (None, why); the
    child's exit code when it died, None when it was stopped at ``timeout``."""
    ctx = mp.get_context("fork")
    recv, send = ctx.Pipe(duplex=False)

    held = HeldInterrupts()

    def child():
        held.restore()
        _quiet(log.fileno())
        faulthandler.disable()  # an abort here is expected to be reported by the parent, not dumped
        try:
            send.send(("ok", work()))
        except BaseException as exc:
            send.send(("error", f"{type(exc).__name__}: {exc}"))

    proc = ctx.Process(target=child, daemon=True)
    held.hold()  # a Ctrl-C inside the fork's handlers would be printed and lost: raised once it is done
    try:
        proc.start()
    except BaseException:
        held.restore()
        raise
    send.close()
    try:
        held.release()
        if not recv.poll(timeout):
            proc.kill()
            return None
        status, value = recv.recv()
    except EOFError:
        proc.join()
        return proc.exitcode
    finally:
        recv.close()
        proc.join(timeout=10)
    return (value, "") if status == "ok" else (None, f"rendering failed ({value})")


def build_review(obj, result, settings, *, take, character, source="", fps=None, notes=(), timings=None,
                 truth=None, render=True, weights_track=None, footage=None):
    """The Review of a solved take on ``obj``: the markers carried onto it (when it binds them) and, with
    ``render``, the contact sheet (``render_guarded``: a failed render leaves a note, not an error).
    ``weights_track``: the take's solved weights (a WeightTrack: its head angles are shown);
    ``footage``: a video take's Footage (its frames beside the renders)."""
    basis, note = None, ""
    stab = result.stabilise
    if stab is not None and stab.markers.dim == 3:
        from ..scene.scene_binding import bound_basis  # loads bpy

        try:  # vertex groups, or the binding by position stored on the character
            basis = bound_basis(obj, stab.markers, settings)
        except FacecapError as exc:  # nothing binds the markers, or no shape keys: no binding to show
            note = str(exc)
    geometry, why = marker_geometry(result, basis, settings)
    note = note or why
    sheet = None
    if not render:
        note = "rendering was turned off"
    elif result.frames.size:
        picks = pick_frames(result, fps=fps)
        sheet, failed = render_guarded(lambda: render_sheet(obj, result, geometry, picks))
        note = failed or ("" if geometry is not None else f"no markers drawn: {note}")
    review_timings = dict(timings or {})
    if sheet is not None:
        review_timings["render"] = sheet.seconds
        if footage is not None:
            sheet = dataclasses.replace(sheet, tiles=tuple(with_footage(t, footage) for t in sheet.tiles))
    return Review(result=result, take=take, character=character, settings=settings, source=source, fps=fps,
                  notes=tuple(notes), timings=review_timings, truth=truth, sheet=sheet, sheet_note=note,
                  geometry=geometry, head_angles=head_angles_on(weights_track, result.frames))


def head_angles_on(track, frames):
    """(F, 3) the track's head yaw, pitch, roll (radians) on ``frames`` (NaN where it has no such frame),
    or None when there is no track or it has no head angles."""
    if track is None or getattr(track, "head", None) is None:
        return None
    frames = np.asarray(frames, dtype=np.float64)
    out = np.full((frames.size, 3), np.nan)
    pos = np.clip(np.searchsorted(track.frames, frames), 0, len(track.frames) - 1)
    found = track.frames[pos] == frames
    out[found] = np.asarray(track.head, dtype=np.float64)[pos[found]]
    return out if np.isfinite(out).any() else None


def with_footage(tile, footage):
    """``tile`` with its footage frame (grey, scaled to the render's height) as the source beside it."""
    import cv2  # OpenCV: only for video takes

    try:
        image = footage.frame(int(round(tile.frame)))
    except FacecapError:  # a frame the footage does not hold: the tile shows the render alone
        return tile
    width = max(1, int(round(image.shape[1] * tile.height / image.shape[0])))
    small = cv2.resize(image, (width, tile.height), interpolation=cv2.INTER_AREA)
    rgb = np.repeat(small[:, :, None], 3, axis=2) if small.ndim == 2 else small[:, :, :3]
    return dataclasses.replace(tile, source_png=encode_png(np.ascontiguousarray(rgb, dtype=np.uint8)))


def write_take_review(config, obj, settings, result, *, notes=(), timings=None, truth=None, options=None,
                      say=lambda _m: None, weights_track=None, footage=None):
    """Write a headless take's review page to ``config.output_html``; returns its path.

    ``settings``: the RetargetSettings the solve ran with; ``truth``: a Truth (read before the solve, so
    a bad file fails early); ``options``: ReviewOptions (plotly.js embedded or shared; renders);
    ``weights_track`` / ``footage``: the take's solved weights or footage (see ``build_review``).
    """
    options = options or ReviewOptions()
    say("writing the review page" + (" (rendering the contact sheet)" if options.render else ""))
    source = config.markers_path or config.weights_path or getattr(config.video, "path", "")
    blend = config.target_blend.name if config.target_blend is not None else "the open .blend"
    review = build_review(obj, result, settings, take=config.action_name, character=f"{blend}: {config.target_object}",
                          source=str(source), fps=_fps(result, config), notes=notes, timings=timings, truth=truth,
                          render=options.render, weights_track=weights_track, footage=footage)
    if review.sheet is None and review.sheet_note and options.render:
        say(f"warning: review page without a contact sheet: {review.sheet_note}")
    written = write_review_page(config.output_html, review, plotly_js=options.plotly_js)
    renders = f"renders {review.sheet.seconds:.1f} s, " if review.sheet is not None else ""
    say(f"review page: {written['bytes'] / 1e6:.1f} MB ({renders}page {written['seconds']:.1f} s)")
    return config.output_html


def _fps(result, config):
    stab = result.stabilise
    if stab is not None and getattr(stab.markers, "fps", None):
        return float(stab.markers.fps)
    return config.fps


def read_review_truth(config):
    """The ``--truth`` weights of a take that writes a review page (None without either)."""
    if config.output_html is None or config.truth_path is None:
        return None
    return read_truth(config.truth_path)


def review_flags(config, html=None, truth=None):
    """``config`` with ``retarget --html`` / ``--truth`` applied (paths relative to the working folder)."""
    if html is not None:
        config = dataclasses.replace(config, output_html=user_path(html))
    if truth is not None:
        if config.output_html is None:
            raise ConfigError("--truth is shown on the review page: give --html or [output] html", path=config.path)
        config = dataclasses.replace(config, truth_path=user_path(truth))
    return config


def export_scene_review(settings, scene, path, *, truth=None, render=True):
    """*Export Review Report*: solve the sidebar's take (the request *Solve and Key* makes, nothing keyed)
    and write its review page to ``path``. Returns {"path", "bytes", "seconds", "note"}."""
    import bpy  # bpy: Blender starts on first import

    from ..scene.scene_solve import request_from_scene  # loads bpy

    path = Path(bpy.path.abspath(str(path)))
    truth_data = None
    truth_file = Path(bpy.path.abspath(str(truth))) if truth else None
    # the output policy; replacing an existing file was chosen in the file browser
    check_outputs([Output("the review page", path, "html")], {"the truth weights": truth_file,
                                                              "the open .blend": bpy.data.filepath or None},
                  overwrite=True)
    if truth_file is not None:
        truth_data = read_truth(truth_file)
    request = request_from_scene(settings, scene)
    result = solve(request)
    blend = Path(bpy.data.filepath).name or "unsaved .blend"
    review = build_review(settings.target, result, request.settings, take=settings.take_name or "take",
                          character=f"{blend}: {settings.target.name}", source=bpy.path.abspath(settings.markers_path),
                          fps=settings.fps, truth=truth_data, render=render,
                          weights_track=getattr(request.inputs, "weights", None))
    written = write_review_page(path, review)
    return {**written, "note": "" if review.sheet is not None else review.sheet_note}
