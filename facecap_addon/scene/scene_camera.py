"""The scene's camera as ``solvers.character.camera.Camera``: how a 2D take's tracks see the character."""

import bpy
import numpy as np

from ...solvers.character.camera import Camera
from ...solvers.errors import FacecapError


def camera_from_scene(scene, name=None, *, object_matrix=None, resolution=None):
    """``solvers.camera.Camera`` of the scene camera (or the camera object ``name``).

    ``object_matrix`` (a character's ``matrix_world``) makes the camera see that object's local
    coordinates, where its bound points and shape deltas live. ``resolution`` (width, height) gives
    pixels of footage whose size differs from the render resolution (same aspect expected).
    """

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
