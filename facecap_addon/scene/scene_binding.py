"""The scene side of binding: the character the geometric solve sees, the binding stored on it,
and its bound points shown as empties.

A binding by position (``map``, ``nearest``) is stored on the character object, as the ID property
``facecap_binding`` (JSON: mode, per marker the corner vertices, barycentric weights, distance, bound),
so it is saved in the .blend, undone with the object and used by every re-solve of the sidebar
without binding again; the command line writes it into its output .blend too. Vertex-group binding
needs no storage (the groups are the binding).
"""

import json

import bpy
import numpy as np

from ...solvers.character.binding_map import BindingSettings
from ...solvers.errors import FacecapError
from ...solvers.pipeline.binding import BoundCharacter, bind_character
from .scene_data import basis_from_object, mesh_from_object

#: ID property of the character object holding its binding by position.
PROPERTY = "facecap_binding"
#: Collection of the empties that show the bound points.
COLLECTION = "FaceCap Binding"
#: Custom property tagging those empties (the marker's name).
TAG = "facecap_bound_marker"
#: Display size of a bound point, mm.
POINT_MM = 1.5


def stored_record(obj):
    """The binding stored on ``obj`` (a dict), or None."""
    text = obj.get(PROPERTY) if obj is not None else None
    if not text:
        return None
    try:
        return json.loads(text)
    except (TypeError, ValueError):
        raise FacecapError(f"the binding stored on '{obj.name}' is damaged; bind the markers again") from None


def store_record(obj, record):
    """Store ``record`` (None: remove it) on ``obj``."""
    if record is None:
        if PROPERTY in obj:
            del obj[PROPERTY]
        return
    obj[PROPERTY] = json.dumps(record)


def mode_family(mode):
    """"map" or "nearest" of a binding's mode ("nearest (landmarks)" -> "nearest")."""
    return str(mode).split(" ")[0]


def geometric_character(obj, markers, settings, binding, *, rebind=False, store=True, driven=False):
    """The character as the geometric strategy sees it (``BoundCharacter``), bound as ``binding``
    (BindingSettings) says; its shapes leave out the keys drivers set unless ``driven`` (a rig's
    binding, whose keys its drivers set).

    Vertex groups are read every time. A binding by position stored on ``obj`` in the same mode is
    used as it is unless ``rebind``; otherwise the markers are bound and, with ``store``, the
    binding is stored on ``obj``.
    """
    if not binding.by_position:
        basis = basis_from_object(obj, markers.names, driven=driven)
        table = {n: (n in basis.marker_names, None) for n in markers.names}
        missing = [n for n, (ok, _) in table.items() if not ok]
        notes = (f"{len(missing)} marker(s) have no vertex group on '{obj.name}': {missing}",) if missing else ()
        return BoundCharacter(basis, "vertex_groups", table, None, notes)
    mesh = mesh_from_object(obj, driven=driven)
    record = None if rebind else stored_record(obj)
    if record is not None and mode_family(record.get("mode")) == binding.mode:
        try:
            return bind_character(mesh, markers, settings, binding, record=record)
        except FacecapError as exc:
            if "bind the markers again" not in str(exc):
                raise
    bound = bind_character(mesh, markers, settings, binding)
    if store:
        store_record(obj, bound.record)
    return bound


def bound_basis(obj, markers, settings):
    """The character's shapes where ``markers`` sit on ``obj``, however they were bound: the binding by
    position stored on it (``map`` or ``nearest``) when there is one, else its vertex groups."""
    record = stored_record(obj)
    if record is not None:
        binding = BindingSettings(mode=mode_family(record.get("mode")))
        return bind_character(mesh_from_object(obj), markers, settings, binding, record=record).basis
    return basis_from_object(obj, markers.names)


def binding_from_sidebar(settings):
    """BindingSettings from the Take panel's binding settings."""
    mode = settings.binding_mode
    landmarks = tuple((row.name, row.vertex_group) for row in settings.binding_landmarks
                      if row.name and row.vertex_group)
    if mode == "nearest" and landmarks and len(landmarks) < 3:
        raise FacecapError(f"landmarks: {len(landmarks)} complete row(s); give at least 3 (marker and vertex group), "
                           "or none for the automatic alignment")
    map_path = bpy.path.abspath(settings.binding_map) if settings.binding_map else None
    if mode == "map" and not map_path:
        raise FacecapError("binding mode Map needs a marker,target CSV (Take panel > Binding > Map)")
    return BindingSettings(mode=mode, map_path=map_path, landmarks=landmarks if mode == "nearest" else (),
                           max_distance_mm=settings.binding_max_distance)


def show_markers(settings, bound):
    """The marker list's read-outs (bound, distance) and the binding summary from ``bound``."""
    for item in settings.markers:
        ok, dist = bound.markers.get(item.name, (False, None))
        item.bound = bool(ok)
        item.bind_distance = -1.0 if dist is None else float(dist)
    settings.binding_summary = bound.summary()


def draw_points(scene, obj, record):
    """One empty per bound marker at its point on ``obj``'s neutral surface (parented to ``obj``), in
    the collection COLLECTION; earlier ones for ``obj`` are removed. Returns the empties."""
    clear_points(obj)
    if record is None:
        return []
    coll = bpy.data.collections.get(COLLECTION)
    if coll is None:
        coll = bpy.data.collections.new(COLLECTION)
    if coll.name not in scene.collection.children:
        scene.collection.children.link(coll)
    mesh = mesh_from_object(obj, driven=True)  # its size only
    m = len(record["names"])
    corners = np.asarray(record["corners"], dtype=np.int64).reshape(m, 3)
    bary = np.asarray(record["barycentric"], dtype=np.float64).reshape(m, 3)
    size = POINT_MM / mesh.mm_per_unit * float(np.mean(np.abs(obj.matrix_world.to_scale())) or 1.0)
    out = []
    for name, c, b, ok in zip(record["names"], corners, bary, record["bound"]):
        if not ok:
            continue
        empty = bpy.data.objects.new(f"{name} (bound)", None)
        empty.empty_display_type = "SPHERE"
        empty.empty_display_size = size
        empty[TAG] = name
        empty.parent = obj
        empty.location = tuple(b @ mesh.vertices[c])  # the parent's local space: the rest surface
        coll.objects.link(empty)
        out.append(empty)
    return out


def clear_points(obj):
    """Remove the empties showing ``obj``'s bound points."""
    for empty in [o for o in bpy.data.objects if o.get(TAG) is not None and o.parent == obj]:
        bpy.data.objects.remove(empty, do_unlink=True)
