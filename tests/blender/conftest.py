"""Blender test fixtures: an isolated user folder, the add-on registered once, a fresh scene per test."""

import os
import tempfile

# Point Blender's user folders at a temporary directory *before* bpy is imported.
_USER = tempfile.mkdtemp(prefix="facecap-blender-user-")
for _var in (
    "BLENDER_USER_RESOURCES",
    "BLENDER_USER_CONFIG",
    "BLENDER_USER_SCRIPTS",
    "BLENDER_USER_EXTENSIONS",
    "BLENDER_USER_DATAFILES",
):
    os.environ.setdefault(_var, os.path.join(_USER, _var.lower()))

import bpy  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

import facecap  # noqa: E402


@pytest.fixture(scope="session", autouse=True)
def registered_addon():
    facecap.register()
    yield
    facecap.unregister()


@pytest.fixture
def empty_scene():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    yield bpy.context.scene


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
