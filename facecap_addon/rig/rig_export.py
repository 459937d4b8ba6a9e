"""Delivery of a rig's take: the mesh and its armature with the bone animation, as glTF or FBX.

Game engines take bones, not controls or drivers: the exporter samples the evaluated scene at
every frame of the take (the solve layer, the animator's layer above it, the rig's constraints and
drivers), keeping the deforming bones (``export_def_bones`` / ``use_armature_deform_only``) and the
mesh's shape-key weights. The selection and frame range of the scene are put back afterwards.
"""

from pathlib import Path

import bpy
import numpy as np

from ...solvers.errors import FacecapError
from ...solvers.io.files import atomic_path
from ..scene.export import FORMATS


def _call(operator, **options):
    """An exporter with the options this Blender version has (they differ a little across 4.2-5.x)."""
    known = set(operator.get_rna_type().properties.keys())
    if "FINISHED" not in operator(**{k: v for k, v in options.items() if k in known}):
        raise FacecapError(f"Blender's {operator.idname_py()} exporter did not finish")


def armatures_of(mesh):
    """The armatures deforming ``mesh`` (its Armature modifiers' objects)."""
    return [m.object for m in mesh.modifiers if m.type == "ARMATURE" and m.object is not None]


def export_rig_take(mesh, path, *, frames, take_name="FaceCap"):
    """Write ``mesh`` and its armatures with the take's sampled animation to ``path`` (.glb or .fbx)."""
    path = Path(path)
    fmt = FORMATS.get(path.suffix.lower())
    if fmt is None:
        raise FacecapError(f"{path}: export needs a .glb or .fbx file name")
    objects = [mesh] + armatures_of(mesh)
    scene = bpy.context.scene
    kept = ([o for o in scene.objects if o.select_get()], bpy.context.view_layer.objects.active,
            scene.frame_start, scene.frame_end, scene.frame_current)
    frames = np.asarray(frames, dtype=np.float64)
    try:
        for o in scene.objects:
            o.select_set(o in objects)
        bpy.context.view_layer.objects.active = objects[-1]
        scene.frame_start, scene.frame_end = int(np.floor(frames.min())), int(np.ceil(frames.max()))
        with atomic_path(path, suffix=path.suffix) as tmp:
            if fmt == "GLTF":
                _call(bpy.ops.export_scene.gltf, filepath=str(tmp), export_format="GLB", use_selection=True,
                      export_animations=True, export_animation_mode="SCENE", export_def_bones=True,
                      export_force_sampling=True, export_frame_range=True, export_morph=True,
                      export_morph_animation=True, export_nla_strips_merged_animation_name=take_name,
                      export_apply=False)
            else:
                _call(bpy.ops.export_scene.fbx, filepath=str(tmp), use_selection=True, bake_anim=True,
                      bake_anim_use_all_actions=False, bake_anim_use_nla_strips=False, bake_anim_step=1.0,
                      bake_anim_simplify_factor=0.0, use_armature_deform_only=True, add_leaf_bones=False,
                      use_mesh_modifiers=False)
    finally:
        selected, active, first, last, current = kept
        for o in scene.objects:
            o.select_set(o in selected)
        bpy.context.view_layer.objects.active = active
        scene.frame_start, scene.frame_end = first, last
        scene.frame_set(current)
    return path
