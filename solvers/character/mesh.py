"""A character's mesh as binding needs it, and the ``Basis`` sampled at wherever its markers are bound.

A marker samples the shape keys at a weighted sum of vertices: a vertex group's members with its
normalised weights (``mode = "vertex_groups"``: the weighted centroid, as the add-on always did), or
the three corners of a triangle with barycentric weights (``map`` and ``nearest``: a point on the
surface). Shape-key deltas are read only for the vertices some marker needs (``CharacterMesh.deltas_at``),
so a large character is never held as (K, V, 3) at once.
"""

from dataclasses import dataclass, field

import numpy as np

from ..errors import FacecapError
from .basis import Basis


@dataclass(frozen=True, eq=False)
class CharacterMesh:
    """The character's neutral surface, vertex groups and shape keys.

    Attributes
    ----------
    vertices : ndarray (V, 3)
        Rest positions (the reference shape key), mesh units.
    triangles : ndarray (T, 3) int
    shape_names : tuple of str, length K
    lower, upper : ndarray (K,)
        Slider ranges.
    deltas_at : callable
        ``deltas_at(ids)`` -> (K, len(ids), 3): each shape minus its relative key at vertices ``ids``.
    vertex_groups : dict
        ``{group name: (vertex indices (n,), weights (n,) summing to 1)}``.
    mm_per_unit : float
        Millimetres per mesh unit (1000 for a metre-scale rig).
    name : str
    """

    vertices: np.ndarray
    triangles: np.ndarray
    shape_names: tuple
    lower: np.ndarray
    upper: np.ndarray
    deltas_at: object
    vertex_groups: dict = field(default_factory=dict)
    mm_per_unit: float = 1000.0
    name: str = "character"

    @classmethod
    def from_arrays(cls, vertices, triangles, shape_names, deltas, *, lower=None, upper=None, vertex_groups=None,
                    mm_per_unit=1000.0, name="character"):
        """A mesh whose per-vertex shape deltas (K, V, 3) are in memory (tests, scripts)."""
        deltas = np.asarray(deltas)
        k = len(shape_names)
        if deltas.shape != (k, len(vertices), 3):
            raise FacecapError(f"{name}: deltas must have shape ({k}, {len(vertices)}, 3); got {deltas.shape}")
        groups = {g: normalised_group(g, idx, w) for g, (idx, w) in (vertex_groups or {}).items()}
        return cls(np.asarray(vertices, dtype=np.float64), np.asarray(triangles, dtype=np.int64), tuple(shape_names),
                   np.zeros(k) if lower is None else np.asarray(lower, dtype=np.float64),
                   np.ones(k) if upper is None else np.asarray(upper, dtype=np.float64),
                   lambda ids: deltas[:, ids], groups, float(mm_per_unit), name)


def normalised_group(name, indices, weights):
    """(indices (n,), weights (n,) summing to 1) of a vertex group, without zero weights."""
    idx = np.asarray(indices, dtype=np.int64)
    w = np.asarray(weights, dtype=np.float64)
    keep = w > 0
    if not keep.any():
        raise FacecapError(f"vertex group '{name}' has no vertices with weight > 0")
    return idx[keep], w[keep] / w[keep].sum()


def group_sampling(mesh, names):
    """{marker: (vertex ids, weights)} for the markers of ``names`` that have a vertex group."""
    return {n: mesh.vertex_groups[n] for n in names if n in mesh.vertex_groups}


def binding_sampling(binding):
    """{marker: (triangle corners (3,), barycentric (3,))} for the bound markers of a ``Binding``."""
    return {n: (binding.mesh_triangles[t], b) for n, t, b, ok in
            zip(binding.names, binding.triangles, binding.barycentric, binding.bound) if ok}


def sampled_basis(mesh, sampling):
    """The ``Basis`` of ``mesh``'s shape keys at the points of ``sampling`` ({marker: (ids, weights)}).

    Raises FacecapError when fewer than 3 markers are bound (the take cannot be aligned).
    """
    names = tuple(sampling)
    if len(names) < 3:
        raise FacecapError(f"{mesh.name}: only {len(names)} marker(s) bound to the character; need at least 3")
    ids = np.unique(np.concatenate([np.asarray(sampling[n][0], dtype=np.int64) for n in names]))
    local = {v: i for i, v in enumerate(ids.tolist())}
    W = np.zeros((len(names), len(ids)))  # (M, n) sampling weights over the needed vertices
    for m, n in enumerate(names):
        vid, w = sampling[n]
        for v, x in zip(np.asarray(vid).tolist(), np.asarray(w, dtype=np.float64).tolist()):
            W[m, local[v]] += x
    neutral = W @ mesh.vertices[ids]
    deltas = np.asarray(mesh.deltas_at(ids), dtype=np.float64)
    return Basis(mesh.shape_names, names, neutral, np.einsum("mn,knd->kmd", W, deltas), mesh.lower, mesh.upper)


__all__ = ["CharacterMesh", "binding_sampling", "group_sampling", "normalised_group", "sampled_basis"]
