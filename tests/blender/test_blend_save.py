"""The output .blend save: written from a scene of its own (no evaluated copy of the keyed action),
and the file holds what the session holds, no more."""

import bpy
import numpy as np

from facecap.facecap_addon.scene import anim
from facecap.facecap_addon.headless.blend_files import save_blend_atomic


def _keyed_mesh(frames=200):
    mesh = bpy.data.meshes.new("Face")
    mesh.vertices.add(3)
    obj = bpy.data.objects.new("Face", mesh)
    bpy.context.scene.collection.objects.link(obj)
    obj.shape_key_add(name="Basis")
    obj.shape_key_add(name="jawOpen", from_mix=False)
    values = np.linspace(0.0, 1.0, frames)[:, None]
    anim.new_action_with_curves(obj.data.shape_keys, name="solve", curves=[('key_blocks["jawOpen"].value', 0)],
                                frames=np.arange(1.0, frames + 1), values=values)
    return obj


def _saved(path):
    with bpy.data.libraries.load(str(path)) as (data_from, _):
        return {"scenes": list(data_from.scenes), "actions": list(data_from.actions),
                "objects": list(data_from.objects)}


def test_one_scene_file_is_saved_whole_without_the_save_context(empty_scene, tmp_path):
    _keyed_mesh()
    scene = bpy.context.scene.name
    out = tmp_path / "out.blend"
    save_blend_atomic(out)
    assert _saved(out) == {"scenes": [scene], "actions": ["solve"], "objects": ["Face"]}
    assert [s.name for s in bpy.data.scenes] == [scene]  # the save's own scene is gone again
    assert bpy.context.scene.name == scene


def test_a_file_of_several_scenes_is_saved_as_it_is(empty_scene, tmp_path):
    _keyed_mesh()
    bpy.data.scenes.new("Second").use_fake_user = True
    out = tmp_path / "out.blend"
    save_blend_atomic(out)
    assert sorted(_saved(out)["scenes"]) == sorted(s.name for s in bpy.data.scenes)
    assert len(bpy.data.scenes) == 2
