"""A 2D take filmed by a scene camera at an angle, solved through that camera (Blender end to end)."""

from dataclasses import replace
import json
from pathlib import Path

import bpy
import numpy as np
from bpy_extras.object_utils import world_to_camera_view
from mathutils import Matrix, Vector
from scene_fixtures import build_character

from facecap.facecap_addon.scene.scene_data import basis_from_object
from facecap.facecap_addon.scene.scene_camera import projection_for
from facecap.solvers import Basis, MarkerSet, RetargetSettings
from facecap.solvers.character.camera import look_at
from facecap.solvers.pipeline import retarget
from facecap.solvers.tools.synthetic.synth import performance_weights

SAMPLES = Path(__file__).resolve().parents[2] / "sample_blends"


def test_geometric_2d_through_the_scene_camera(empty_scene):
    scene = empty_scene
    basis = Basis.load_npz(SAMPLES / "character_basis.npz")
    stable = tuple(m["name"] for m in json.loads((SAMPLES / "marker_layout.json").read_text())["markers"]
                   if m["stable"])
    obj = build_character(basis)
    obj.matrix_world = Matrix.Translation((0.3, -0.2, 1.6)) @ Matrix.Rotation(0.4, 4, "Z")  # not at the origin
    centre = obj.matrix_world @ Vector((0.0, -0.06, 0.0))
    a = np.radians(25.0)  # the camera films the face 25 degrees off its front
    facing = obj.matrix_world.to_3x3() @ Vector((np.sin(a), -np.cos(a), 0.0))
    cam = bpy.data.objects.new("Witness", bpy.data.cameras.new("Witness"))
    scene.collection.objects.link(cam)
    cam.data.lens, cam.data.shift_x = 50.0, 0.03
    cam.matrix_world = Matrix(look_at(tuple(centre + 0.55 * facing), tuple(centre)).tolist())
    scene.render.resolution_x, scene.render.resolution_y = 1280, 720
    bpy.context.view_layer.update()

    W = performance_weights(basis.shape_names, 240, seed=6)
    local = basis.neutral[None] + np.einsum("fk,kmd->fmd", W, basis.deltas)
    M = np.array(obj.matrix_world)
    world = local @ M[:3, :3].T + M[:3, 3]
    ndc = np.array([[tuple(world_to_camera_view(scene, cam, Vector(p)))[:2] for p in frame] for frame in world])
    px = np.stack([ndc[..., 0] * 1280, (1 - ndc[..., 1]) * 720], axis=-1)  # Blender's own projection
    px += np.random.default_rng(0).normal(0, 0.3, px.shape)
    markers = MarkerSet(basis.marker_names, np.arange(1, 241), px, fps=60, units="px", source="witness cam")

    character = basis_from_object(obj, markers.names)
    settings = RetargetSettings(stable, (1, 40))
    through = retarget(markers, character, replace(settings, projection=projection_for(scene, obj, "camera", "Witness")))
    front = retarget(markers, character, replace(settings, projection=projection_for(scene, obj)))
    e_cam = float(np.sqrt(np.mean((through.weights - W) ** 2)))
    e_front = float(np.sqrt(np.mean((front.weights - W) ** 2)))
    print(f"Blender witness camera at 25 deg: weights RMSE camera {e_cam:.4f}, front view {e_front:.4f}")
    assert e_cam <= 0.06 and e_cam < 0.6 * e_front


def test_solve_and_key_a_tracked_2d_take_through_the_sidebar_camera(empty_scene, tmp_path):
    """The artist's path: a 2D take in the scene (as Track Clip Footage leaves it), the Video panel's
    projection set to the camera, Solve and Key; then the same take headless through the CLI."""
    from facecap.facecap_addon.scene import anim, import_scene, layers, take

    scene = empty_scene
    basis = Basis.load_npz(SAMPLES / "character_basis.npz")
    stable = [m["name"] for m in json.loads((SAMPLES / "marker_layout.json").read_text())["markers"] if m["stable"]]
    obj = build_character(basis)
    cam = bpy.data.objects.new("Witness", bpy.data.cameras.new("Witness"))
    scene.collection.objects.link(cam)
    a = np.radians(20.0)
    eye = np.array([0.55 * np.sin(a), -0.06 - 0.55 * np.cos(a), 0.0])
    cam.matrix_world = Matrix(look_at(tuple(eye), (0.0, -0.06, 0.0)).tolist())
    scene.camera = cam
    scene.render.resolution_x, scene.render.resolution_y = 1280, 720
    bpy.context.view_layer.update()
    W = performance_weights(basis.shape_names, 200, seed=2)
    world = basis.neutral[None] + np.einsum("fk,kmd->fmd", W, basis.deltas)
    ndc = np.array([[tuple(world_to_camera_view(scene, cam, Vector(p)))[:2] for p in frame] for frame in world])
    px = np.stack([ndc[..., 0] * 1280, (1 - ndc[..., 1]) * 720], axis=-1)
    markers = MarkerSet(basis.marker_names, np.arange(1, 201), px, fps=60, units="px", source="witness cam")
    coll = import_scene.create_take(scene, markers, "witness")
    s = scene.facecap
    s.marker_collection, s.take_name, s.fps, s.target = coll, "witness", 60.0, obj
    for name in markers.names:
        item = s.markers.add()
        item.name, item.stable = name, name in stable
    s.neutral_first, s.neutral_last = 1, 40
    back = take.markers_from_collection(s)
    assert back.dim == 2 and back.units == "px"
    np.testing.assert_allclose(back.positions, px, atol=2e-3)  # float32 keys at 1 px = 1 mm

    errors = {}
    for projection in ("front", "camera"):
        s.video.projection = projection
        assert bpy.ops.facecap.solve() == {"FINISHED"}
        key = obj.data.shape_keys
        curves = [(layers.shape_path(n), 0) for n in basis.shape_names]
        keyed = anim.read_curves(key, curves, action=layers.solved_action(key))[1]
        errors[projection] = float(np.sqrt(np.mean((keyed - W) ** 2)))
    print(f"sidebar 2D solve at 20 deg: weights RMSE camera {errors['camera']:.4f}, front {errors['front']:.4f}")
    assert errors["camera"] <= 0.06 and errors["camera"] < errors["front"]
    # The same take headless: `[solve] projection = "camera"` reads the .blend's scene camera.
    import subprocess
    import sys

    from facecap.solvers.io.csv import read_weights_csv, write_markers_csv

    out = tmp_path
    write_markers_csv(out / "tracks.csv", markers)
    bpy.ops.wm.save_as_mainfile(filepath=str(out / "scene.blend"), copy=True)
    (out / "take.toml").write_text(
        '[target]\nblend = "scene.blend"\nobject = "Face"\n[source]\nmarkers = "tracks.csv"\nunits = "px"\nfps = 60\n'
        f'[binding]\nvertex_groups = true\n[stabilise]\nmarkers = {json.dumps(stable)}\n[neutral]\nframes = [1, 40]\n'
        '[solve]\nprojection = "camera"\n[output]\nweights = "weights.csv"\n')
    proc = subprocess.run([sys.executable, "-m", "facecap", "retarget", "--config", str(out / "take.toml")],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    _, names, headless = read_weights_csv(out / "weights.csv")
    assert tuple(names) == basis.shape_names
    np.testing.assert_allclose(headless, keyed, atol=2e-3)  # float32 keys in the scene vs the CSV's pixels
