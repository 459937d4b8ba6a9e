"""Scenes built through bpy.data for the Blender tests (imported by name: conftest modules are not importable)."""

from types import SimpleNamespace

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


class LayoutStub:
    """UILayout stand-in for panel draw tests: checks every property, operator and list a panel references."""

    def __init__(self):
        self.calls = []

    def prop(self, data, name, **_kw):
        assert name in data.bl_rna.properties, f"{type(data).__name__} has no property '{name}'"
        self.calls.append(("prop", name))

    def operator(self, idname, **_kw):
        module, op = idname.split(".")
        assert hasattr(getattr(bpy.ops, module), op), f"no operator {idname}"
        self.calls.append(("operator", idname))
        return SimpleNamespace()  # panels may set operator properties on it

    def template_list(self, list_type, _list_id, data, prop, active_data, active_prop, **_kw):
        assert hasattr(bpy.types, list_type)
        assert prop in data.bl_rna.properties and active_prop in active_data.bl_rna.properties
        self.calls.append(("template_list", prop))

    def prop_search(self, data, name, search_data, search_name, **_kw):
        assert name in data.bl_rna.properties, f"{type(data).__name__} has no property '{name}'"
        assert search_name in search_data.bl_rna.properties, f"{type(search_data).__name__} has no '{search_name}'"
        self.calls.append(("prop_search", name))

    def label(self, **_kw):
        self.calls.append(("label", _kw.get("text")))

    def row(self, **_kw):
        return self

    column = box = row


def sub_panels(name):
    """The sub-panels of sidebar panel ``name`` in the order they are drawn."""
    return [cls for cls in bpy.types.Panel.__subclasses__() if getattr(cls, "bl_parent_id", "") == name
            and hasattr(bpy.types, cls.__name__)]


def draw_panel(name, layout=None):
    """Draw panel ``name`` and every sub-panel that applies (its ``poll``), as Blender shows them opened;
    returns the LayoutStub with every call."""
    layout = LayoutStub() if layout is None else layout
    stub = SimpleNamespace(layout=layout)
    getattr(bpy.types, name).draw(stub, bpy.context)
    for cls in sub_panels(name):
        if not hasattr(cls, "poll") or cls.poll(bpy.context):
            cls.draw(stub, bpy.context)
    return layout


def modal_driver(operator):
    """A class running ``operator``'s own modal methods on a plain object (Blender builds operator
    instances itself): ``Driver(session)``, then ``modal``/``cancel`` as Blender would call them."""

    class Driver:
        modal, cancel, _stop, _write = operator.modal, operator.cancel, operator._stop, operator._write

        def __init__(self, session):
            self._session, self._timer, self.reports = session, None, []

        def report(self, kind, message):
            self.reports.append((kind.pop(), message))

    return Driver
