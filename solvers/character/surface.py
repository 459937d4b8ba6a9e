"""A character's neutral surface as triangles: closest points (triangle + barycentric coordinates).

The triangles' centroids are kept in a k-d tree (SciPy's ``cKDTree``; the extension bundles SciPy): the
approximate query tests the k triangles whose centroids are nearest each point, which is what alignment
iterations need (tens of markers, thousands of triangles, many iterations); the exact one tests only the
triangles whose centroids are near enough to hold a closer point than the approximate answer.
"""

from dataclasses import dataclass

import numpy as np

from ..errors import FacecapError

#: Triangles whose closest points the exact query starts from (the nearest centroids), before it widens.
EXACT_START = 8
#: Points per block of the exact query (bounds the temporary memory where a mesh has huge triangles).
EXACT_BLOCK = 256


@dataclass(frozen=True, eq=False)
class Surface:
    """Triangles of a mesh with what the queries need, computed once.

    Attributes
    ----------
    vertices : ndarray (V, 3)
    triangles : ndarray (T, 3) int
    normals : ndarray (T, 3)
        Unit face normals (zero for degenerate triangles).
    vertex_triangles : ndarray (V, k) int
        Triangles around each vertex, padded with -1.
    centroids : ndarray (T, 3)
        Triangle centroids (the queries' candidates).
    tree : scipy.spatial.cKDTree
        The centroids' k-d tree.
    reach : float
        The largest distance from a triangle's centroid to its corners: no point of a triangle is farther
        than that from its centroid.
    vertex_normals : ndarray (V, 3)
        Unit normals at the vertices (the area-weighted mean of their triangles'): ``smooth_normals``.
    """

    vertices: np.ndarray
    triangles: np.ndarray
    normals: np.ndarray
    vertex_triangles: np.ndarray
    centroids: np.ndarray
    tree: object
    reach: float
    vertex_normals: np.ndarray = None

    @property
    def n_triangles(self):
        return len(self.triangles)

    def corners(self, tri):
        """(a, b, c) corner arrays (N, 3) of triangles ``tri`` (N,)."""
        v = self.vertices[self.triangles[tri]]
        return v[:, 0], v[:, 1], v[:, 2]


def triangulate(faces):
    """(T, 3) int triangles from polygons (tuples of vertex indices, fan-split)."""
    tris = [(f[0], f[k], f[k + 1]) for f in faces for k in range(1, len(f) - 1)]
    return np.asarray(tris, dtype=np.int64).reshape(-1, 3)


def skin_triangles(n_vertices, triangles):
    """The triangles of the largest connected piece of a mesh (by triangle count): a face's skin, without the
    eyeballs, teeth or tongue that characters model as separate pieces (a marker never sits on those)."""
    from scipy.sparse import coo_matrix  # scipy: only binding by position needs it
    from scipy.sparse.csgraph import connected_components  # scipy, as above

    tris = np.asarray(triangles, dtype=np.int64)
    rows = np.concatenate([tris[:, 0], tris[:, 1]])
    cols = np.concatenate([tris[:, 1], tris[:, 2]])
    graph = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n_vertices, n_vertices))
    _, labels = connected_components(graph, directed=False)
    owner = labels[tris[:, 0]]
    return tris[owner == np.bincount(owner).argmax()]


def make_surface(vertices, triangles):
    """A :class:`Surface` from (V, 3) vertices and (T, 3) triangles (or polygons, fan-split)."""
    vertices = np.asarray(vertices, dtype=np.float64)
    if vertices.ndim != 2 or vertices.shape[1] != 3 or len(vertices) < 3:
        raise FacecapError(f"surface: vertices must have shape (V, 3) with V >= 3; got {vertices.shape}")
    if not np.isfinite(vertices).all():
        raise FacecapError("surface: vertices must be finite")
    tris = np.asarray(triangles) if isinstance(triangles, np.ndarray) else triangulate(triangles)
    tris = np.asarray(tris, dtype=np.int64)
    if tris.ndim != 2 or tris.shape[1] != 3 or len(tris) == 0:
        raise FacecapError(f"surface: triangles must have shape (T, 3) with T >= 1; got {tris.shape}")
    if tris.min() < 0 or tris.max() >= len(vertices):
        raise FacecapError(f"surface: triangle corners must index the {len(vertices)} vertices")
    a, b, c = (vertices[tris[:, k]] for k in range(3))
    n = np.cross(b - a, c - a)
    length = np.linalg.norm(n, axis=1, keepdims=True)
    normals = np.divide(n, length, out=np.zeros_like(n), where=length > 0)
    centroids = (a + b + c) / 3.0
    from scipy.spatial import cKDTree  # scipy: loaded when a character is first bound, not with the package

    reach = float(max(np.linalg.norm(x - centroids, axis=1).max() for x in (a, b, c)))
    return Surface(vertices, tris, normals, _vertex_triangles(len(vertices), tris), centroids, cKDTree(centroids),
                   reach, vertex_normals(vertices, tris, n))


def vertex_normals(vertices, triangles, face_cross=None):
    """(V, 3) unit vertex normals: the sum of the cross products (area-weighted normals) of each vertex's
    triangles, normalised (zero for a vertex of no triangle)."""
    tris = np.asarray(triangles, dtype=np.int64)
    if face_cross is None:
        a, b, c = (vertices[tris[:, k]] for k in range(3))
        face_cross = np.cross(b - a, c - a)
    acc = np.zeros((len(vertices), 3))
    for k in range(3):
        np.add.at(acc, tris[:, k], face_cross)
    length = np.linalg.norm(acc, axis=1, keepdims=True)
    return np.divide(acc, length, out=np.zeros_like(acc), where=length > 0)


def smooth_normals(normals, triangles, triangle, barycentric):
    """Unit normals (N, 3) at barycentric points, interpolated from the vertex ``normals`` (V, 3): continuous across
    edges, so a point-to-plane residual does not jump when its closest point moves to the next triangle (nor with
    which of two triangles the rounding of an edge's closest point picks)."""
    n = interpolate(normals, triangles, triangle, barycentric)
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, length, out=np.zeros_like(n), where=length > 0)


def _vertex_triangles(n_vertices, tris):
    owner = np.repeat(np.arange(len(tris)), 3)
    corner = tris.ravel()
    order = np.argsort(corner, kind="stable")
    corner, owner = corner[order], owner[order]
    counts = np.bincount(corner, minlength=n_vertices)
    width = max(int(counts.max()), 1)
    start = np.concatenate([[0], np.cumsum(counts)[:-1]])
    slot = np.arange(len(corner)) - start[corner]
    out = np.full((n_vertices, width), -1, dtype=np.int64)
    out[corner, slot] = owner
    return out


def closest_on_triangles(p, a, b, c):
    """Closest points on triangles (a, b, c) to points ``p``, all (N, 3).

    Returns (q (N, 3), barycentric (N, 3)) with q = bary[:, 0] a + bary[:, 1] b + bary[:, 2] c
    (Ericson, Real-Time Collision Detection, 5.1.5, vectorised over the Voronoi regions).
    """
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = _dot(ab, ap), _dot(ac, ap)
    bp = p - b
    d3, d4 = _dot(ab, bp), _dot(ac, bp)
    cp = p - c
    d5, d6 = _dot(ab, cp), _dot(ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    bary = np.empty_like(p)
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        v, w = vb / denom, vc / denom
        bary[:] = np.stack([1.0 - v - w, v, w], axis=1)
        region = [
            ((d1 <= 0) & (d2 <= 0), (1.0, 0.0, 0.0)),  # vertex a
            ((d3 >= 0) & (d4 <= d3), (0.0, 1.0, 0.0)),  # vertex b
            ((d6 >= 0) & (d5 <= d6), (0.0, 0.0, 1.0)),  # vertex c
        ]
        edges = [
            ((vc <= 0) & (d1 >= 0) & (d3 <= 0), d1 / (d1 - d3), (0, 1)),  # edge ab
            ((vb <= 0) & (d2 >= 0) & (d6 <= 0), d2 / (d2 - d6), (0, 2)),  # edge ac
            ((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0), (d4 - d3) / ((d4 - d3) + (d5 - d6)), (1, 2)),  # edge bc
        ]
    done = np.zeros(len(p), dtype=bool)
    for mask, weights in region:
        mask = mask & ~done
        bary[mask] = weights
        done |= mask
    for mask, t, (i, j) in edges:
        mask = mask & ~done
        bary[mask] = 0.0
        bary[mask, i] = 1.0 - t[mask]
        bary[mask, j] = t[mask]
        done |= mask
    bad = ~np.isfinite(bary).all(axis=1)  # degenerate triangles: their first corner
    bary[bad] = (1.0, 0.0, 0.0)
    q = bary[:, :1] * a + bary[:, 1:2] * b + bary[:, 2:] * c
    return q, bary


def _dot(u, v):
    return np.einsum("ij,ij->i", u, v)


def closest_points(surface, points, *, candidates=None):
    """Closest surface points to (N, 3) ``points``.

    Parameters
    ----------
    surface : Surface
    points : ndarray (N, 3)
    candidates : int or None
        None gives the exact closest points; k tests the k triangles whose centroids are nearest each
        point (exact unless the mesh mixes very large and small triangles there).

    Returns
    -------
    triangle : ndarray (N,) int
    barycentric : ndarray (N, 3)
    closest : ndarray (N, 3)
    distance : ndarray (N,)
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    finite = np.isfinite(points).all(axis=1)
    if not finite.all():  # a point without a position has no closest point: -1 and NaN
        out = (np.full(len(points), -1), np.full((len(points), 3), np.nan), np.full((len(points), 3), np.nan),
               np.full(len(points), np.nan))
        for whole, part in zip(out, closest_points(surface, points[finite], candidates=candidates)):
            whole[finite] = part
        return out
    tri = nearest_triangles(surface, points, candidates or EXACT_START)
    if candidates is not None:
        return _best_of(surface, points, tri)
    parts = [_best_of(surface, points[i:i + EXACT_BLOCK], _exact_candidates(surface, points[i:i + EXACT_BLOCK],
                                                                              tri[i:i + EXACT_BLOCK]))
             for i in range(0, len(points), EXACT_BLOCK)]
    return tuple(np.concatenate(x) for x in zip(*parts)) if parts else _best_of(surface, points, tri)


def _best_of(surface, points, tri):
    """closest_points' answer among the (N, k) candidate triangles ``tri`` of each point (-1: none)."""
    n, k = tri.shape
    flat = tri.ravel()
    a, b, c = surface.corners(np.where(flat < 0, 0, flat))
    p = np.repeat(points, k, axis=0)
    q, bary = closest_on_triangles(p, a, b, c)
    d2 = np.sum((p - q) ** 2, axis=1).reshape(n, k)
    d2[tri < 0] = np.inf
    best = np.argmin(d2, axis=1)
    rows = np.arange(n) * k + best
    return tri[np.arange(n), best], bary[rows], q[rows], np.sqrt(d2[np.arange(n), best])


def nearest_triangles(surface, points, k, *, distances=False):
    """(N, k) ids of the triangles whose centroids are nearest each point, nearest first; with
    ``distances``, also their (N, k) squared distances."""
    k = min(int(k), surface.n_triangles)
    d, ids = surface.tree.query(np.asarray(points, dtype=np.float64).reshape(-1, 3), k=k)
    ids, d = np.asarray(ids, dtype=np.int64).reshape(-1, k), np.asarray(d).reshape(-1, k)
    return (ids, d**2) if distances else ids


def _exact_candidates(surface, points, start):
    """(N, m) candidate triangles (-1 padded) that surely hold each point's closest surface point: the
    closest point among ``start`` is at distance d, and a triangle holding a closer one has its centroid
    within d + reach of the point."""
    _, _, _, d = _best_of(surface, points, start)
    found = surface.tree.query_ball_point(points, d + surface.reach * (1 + 1e-9) + 1e-12)
    width = max(len(f) for f in found)
    out = np.full((len(points), width), -1, dtype=np.int64)
    for i, f in enumerate(found):
        out[i, :len(f)] = f
    return out


def interpolate(values, triangles, triangle, barycentric):
    """Per-vertex ``values`` (..., V, D) at barycentric points: (..., N, D).

    Parameters
    ----------
    values : ndarray (..., V, D)
    triangles : ndarray (T, 3)
    triangle : ndarray (N,) int
    barycentric : ndarray (N, 3)
    """
    corners = triangles[triangle]  # (N, 3)
    v = np.asarray(values)[..., corners, :]  # (..., N, 3, D)
    return np.einsum("...ncd,nc->...nd", v, barycentric)


__all__ = ["Surface", "closest_on_triangles", "closest_points", "interpolate", "make_surface", "nearest_triangles",
           "smooth_normals", "triangulate", "vertex_normals"]
