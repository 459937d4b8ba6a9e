"""The solver's camera model against Blender's own projection (bpy_extras.object_utils.world_to_camera_view)."""

import bpy
import numpy as np
import pytest
from bpy_extras.object_utils import world_to_camera_view
from mathutils import Matrix, Vector

from facecap.facecap_addon.scene.scene_camera import camera_from_scene
from facecap.solvers.character.camera import look_at


def add_camera(scene, *, lens=35.0, sensor=(36.0, 24.0), fit="AUTO", shift=(0.0, 0.0), location=(0.4, -0.9, 0.3),
               ortho=False):
    data = bpy.data.cameras.new("Cam")
    data.lens, data.sensor_width, data.sensor_height, data.sensor_fit = lens, sensor[0], sensor[1], fit
    data.shift_x, data.shift_y = shift
    if ortho:
        data.type, data.ortho_scale = "ORTHO", 0.5
    cam = bpy.data.objects.new("Cam", data)
    scene.collection.objects.link(cam)
    cam.matrix_world = Matrix(look_at(location, (0.0, 0.0, 0.05)).tolist())
    cam.scale = (2.0, 2.0, 2.0)  # Blender's projection ignores the camera's scale; so must the model
    scene.camera = cam
    bpy.context.view_layer.update()
    return cam


@pytest.mark.parametrize("resolution,fit,shift,aspect,ortho", [
    ((1280, 720, 100), "AUTO", (0.0, 0.0), (1, 1), False),
    ((1920, 1080, 50), "AUTO", (0.12, -0.07), (1, 1), False),
    ((720, 1280, 100), "AUTO", (0.05, 0.1), (1, 1), False),  # portrait: AUTO fits the sensor width vertically
    ((1280, 720, 100), "VERTICAL", (0.1, 0.0), (1, 1), False),
    ((1440, 1080, 100), "HORIZONTAL", (0.0, 0.08), (4, 3), False),  # anamorphic pixels
    ((1280, 720, 100), "AUTO", (0.1, 0.05), (1, 1), True),
])
def test_camera_model_matches_world_to_camera_view(empty_scene, resolution, fit, shift, aspect, ortho):
    scene = empty_scene
    r = scene.render
    r.resolution_x, r.resolution_y, r.resolution_percentage = resolution
    r.pixel_aspect_x, r.pixel_aspect_y = aspect
    cam = add_camera(scene, fit=fit, shift=shift, ortho=ortho)
    model = camera_from_scene(scene)
    w, h = model.width, model.height
    assert (w, h) == (resolution[0] * resolution[2] // 100, resolution[1] * resolution[2] // 100)
    pts = np.random.default_rng(0).normal(scale=0.08, size=(40, 3)) + [0.0, 0.0, 0.05]
    px = model.project(pts)
    depth = model.depth(pts)
    ref = np.array([tuple(world_to_camera_view(scene, cam, Vector(p))) for p in pts])
    np.testing.assert_allclose(px[:, 0] / w, ref[:, 0], atol=1e-6)
    np.testing.assert_allclose(1.0 - px[:, 1] / h, ref[:, 1], atol=1e-6)  # pixels: origin top-left, y down
    np.testing.assert_allclose(depth, ref[:, 2], atol=1e-6)


def test_named_camera_object_space_and_footage_resolution(empty_scene):
    scene = empty_scene
    cam = add_camera(scene, shift=(0.05, 0.0))
    scene.camera = None
    head = bpy.data.objects.new("Head", None)
    scene.collection.objects.link(head)
    head.matrix_world = Matrix.Translation((0.1, 0.2, 1.5)) @ Matrix.Rotation(0.3, 4, "Z")
    bpy.context.view_layer.update()
    with pytest.raises(Exception, match="no camera"):
        camera_from_scene(scene)
    with pytest.raises(Exception, match="'Nope' is not a camera object"):
        camera_from_scene(scene, "Nope")
    local = np.array([[0.01, -0.05, 0.02], [-0.03, -0.04, 0.0]])
    world = np.array([tuple(head.matrix_world @ Vector(p)) for p in local])
    model = camera_from_scene(scene, cam.name)
    seen = camera_from_scene(scene, cam.name, object_matrix=head.matrix_world)
    np.testing.assert_allclose(seen.project(local), model.project(world), atol=1e-9)
    half = camera_from_scene(scene, cam.name, resolution=(960, 540))
    np.testing.assert_allclose(half.project(world), model.project(world) / 2, atol=1e-9)
