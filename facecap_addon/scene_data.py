"""Scene -> numpy adapters: read a character's shape keys at its bound marker points."""

import numpy as np

from ..solvers.character.basis import Basis
from ..solvers.errors import FacecapError


def shape_key_names(obj):
    """Names of the solvable shape keys of ``obj`` (every key block except the reference)."""
    key = getattr(obj.data, "shape_keys", None)
    if key is None:
        return ()
    return tuple(b.name for b in key.key_blocks if b != key.reference_key)


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


def basis_from_object(obj, marker_names=None):
    """Sample ``obj``'s shape keys at the weighted centroids of its marker vertex groups.

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
            "need at least 3 groups named after markers"
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
    for block in key.key_blocks:
        if block == ref:
            continue
        rel = block.relative_key if block.relative_key is not None else ref
        deltas.append(sample(block_coords(block)) - sample(block_coords(rel)))
        shapes.append(block.name)
        lo.append(block.slider_min)
        hi.append(block.slider_max)
    return Basis(tuple(shapes), names, neutral, np.stack(deltas), np.array(lo), np.array(hi))
