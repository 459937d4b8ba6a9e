"""Scene -> numpy adapters: read a character's shape keys at its bound marker points, and its mesh
(rest positions, triangles, vertex groups, shape-key deltas on demand) for binding by position."""

import numpy as np

from ...solvers.character.basis import Basis
from ...solvers.character.mesh import CharacterMesh
from ...solvers.errors import FacecapError
from ..rig.drivers import driven_keys


def shape_key_names(obj):
    """Names of the shape keys of ``obj`` (every key block except the reference)."""
    key = getattr(obj.data, "shape_keys", None)
    if key is None:
        return ()
    return tuple(b.name for b in key.key_blocks if b != key.reference_key)


def solvable_blocks(obj, *, driven=False):
    """The key blocks of ``obj`` a solve drives: every one but the reference and, unless ``driven``,
    those a driver sets (``rig.drivers``: at playback the driver would override their keys)."""
    key = obj.data.shape_keys
    skip = set() if driven else set(driven_keys(obj))
    blocks = [b for b in key.key_blocks if b != key.reference_key and b.name not in skip]
    if not blocks:
        raise FacecapError(f"every shape key of '{obj.name}' is set by a driver, which would override any key: "
                           "solve the controls the drivers read instead ([rig]: a preset or named controls)")
    return blocks


def _coords(collection, n):
    out = np.empty(n * 3, dtype=np.float64)
    collection.foreach_get("co", out)
    return out.reshape(n, 3)


def vertex_group_bindings(obj, names=None):
    """Binding from vertex groups: {group name: (vertex indices, normalised weights)}.

    ``names`` restricts the groups read (markers of a take); groups without vertices are an error.
    """
    wanted = {vg.index: vg.name for vg in obj.vertex_groups if names is None or vg.name in set(names)}
    members = {i: ([], []) for i in wanted}
    for v in obj.data.vertices:
        for g in v.groups:
            if g.group in members and g.weight > 0.0:
                members[g.group][0].append(v.index)
                members[g.group][1].append(g.weight)
    bindings = {}
    for gi, name in wanted.items():
        idx, w = members[gi]
        if not idx:
            raise FacecapError(f"object '{obj.name}': vertex group '{name}' has no vertices with weight > 0")
        w = np.asarray(w, dtype=np.float64)
        bindings[name] = (np.asarray(idx, dtype=np.intp), w / w.sum())
    return bindings


def basis_from_object(obj, marker_names=None, *, driven=False):
    """Sample ``obj``'s shape keys (without the driven ones unless ``driven``) at the weighted
    centroids of its marker vertex groups.

    Parameters
    ----------
    obj : bpy.types.Object, a mesh with shape keys
    marker_names : sequence of str, optional
        Markers to bind (vertex groups of the same name). Default: every vertex group.

    Returns
    -------
    Basis in the object's local space (metres for a metre-scale rig).
    """
    if obj is None or obj.type != "MESH":
        raise FacecapError(f"'{getattr(obj, 'name', obj)}' is not a mesh object")
    key = obj.data.shape_keys
    if key is None or len(key.key_blocks) < 2:
        raise FacecapError(f"object '{obj.name}' has no shape keys to solve for")
    bindings = vertex_group_bindings(obj, marker_names)
    if marker_names is not None:
        bindings = {n: bindings[n] for n in marker_names if n in bindings}
    if len(bindings) < 3:
        raise FacecapError(
            f"object '{obj.name}': only {len(bindings)} marker vertex group(s) found; "
            "need at least 3 groups named after markers, or a binding by position ([binding] mode = \"nearest\" "
            "or \"map\"; the Binding box of the Take panel)"
        )
    n = len(obj.data.vertices)
    names = tuple(bindings)
    idx = [bindings[m][0] for m in names]
    wts = [bindings[m][1] for m in names]

    def sample(co):
        return np.stack([w @ co[i] for i, w in zip(idx, wts)])

    ref = key.reference_key
    cache = {}

    def block_coords(block):
        if block.name not in cache:
            cache[block.name] = _coords(block.data, n)
        return cache[block.name]

    neutral = sample(block_coords(ref))
    shapes, deltas, lo, hi = [], [], [], []
    for block in solvable_blocks(obj, driven=driven):
        rel = block.relative_key if block.relative_key is not None else ref
        deltas.append(sample(block_coords(block)) - sample(block_coords(rel)))
        shapes.append(block.name)
        lo.append(block.slider_min)
        hi.append(block.slider_max)
    return Basis(tuple(shapes), names, neutral, np.stack(deltas), np.array(lo), np.array(hi))


def _group_members(obj):
    """{group index: (vertex indices, weights)} of every vertex group with a vertex of weight > 0."""
    members = {}
    for v in obj.data.vertices:
        for g in v.groups:
            if g.weight > 0.0:
                idx, w = members.setdefault(g.group, ([], []))
                idx.append(v.index)
                w.append(g.weight)
    return members


def mesh_from_object(obj, *, driven=False):
    """``obj``'s rest surface (reference shape key), loop triangles, vertex groups and shape keys
    (without the driven ones unless ``driven``) as a ``CharacterMesh`` (local space). Coordinates are read in bulk (``foreach_get``); a shape key's
    deltas are read when a binding asks for them, at the vertices it needs.

    ``mm_per_unit`` is 1000 x the scene's unit scale x the object's mean world scale.
    """
    if obj is None or obj.type != "MESH":
        raise FacecapError(f"'{getattr(obj, 'name', obj)}' is not a mesh object")
    key = obj.data.shape_keys
    if key is None or len(key.key_blocks) < 2:
        raise FacecapError(f"object '{obj.name}' has no shape keys to solve for")
    me = obj.data
    n = len(me.vertices)
    ref = key.reference_key
    vertices = _coords(ref.data, n)
    me.calc_loop_triangles()
    tris = np.empty(len(me.loop_triangles) * 3, dtype=np.int64)
    me.loop_triangles.foreach_get("vertices", tris)
    if tris.size == 0:
        raise FacecapError(f"object '{obj.name}' has no faces to bind markers to")
    names = {vg.index: vg.name for vg in obj.vertex_groups}
    groups = {names[i]: (np.asarray(idx, dtype=np.int64), np.asarray(w) / np.sum(w))
              for i, (idx, w) in _group_members(obj).items() if i in names}
    blocks = solvable_blocks(obj, driven=driven)

    def deltas_at(ids):
        ids = np.asarray(ids, dtype=np.int64)
        cache = {}

        def at(block):
            if block.name not in cache:
                cache[block.name] = _coords(block.data, n)[ids]  # the whole block is one bulk read
            return cache[block.name]

        return np.stack([at(b) - at(b.relative_key if b.relative_key is not None else ref) for b in blocks])

    scale = float(np.mean(np.abs(obj.matrix_world.to_scale())))
    scene = getattr(obj, "users_scene", ())
    unit = float(scene[0].unit_settings.scale_length) if scene else 1.0
    return CharacterMesh(vertices, tris.reshape(-1, 3), tuple(b.name for b in blocks),
                         np.array([b.slider_min for b in blocks], dtype=np.float64),
                         np.array([b.slider_max for b in blocks], dtype=np.float64),
                         deltas_at, groups, 1000.0 * unit * (scale if scale > 0 else 1.0), obj.name)
