"""Scenes built through bpy.data for the Blender tests (imported by name: conftest modules are not importable)."""

import bpy
import numpy as np


def build_character(basis, name="Face"):
    """A mesh whose vertices are the basis points (plus an offset copy) with one vertex group per marker."""
    n = basis.n_markers
    extra = basis.neutral + np.array([0.0, 0.01, 0.0])  # unbound vertices, so groups are a true subset
    co = np.vstack([basis.neutral, extra])
    mesh = bpy.data.meshes.new(name)
    mesh.vertices.add(len(co))
    mesh.vertices.foreach_set("co", co.astype(np.float32).ravel())
    mesh.update()
    obj = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(obj)
    obj.shape_key_add(name="Basis")
    for k, shape in enumerate(basis.shape_names):
        block = obj.shape_key_add(name=shape, from_mix=False)
        moved = co.copy()
        moved[:n] += basis.deltas[k]
        block.data.foreach_set("co", moved.astype(np.float32).ravel())
    for m, marker in enumerate(basis.marker_names):
        obj.vertex_groups.new(name=marker).add([m], 1.0, "REPLACE")
    return obj
