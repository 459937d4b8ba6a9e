"""A character's neutral surface as triangles: closest points (triangle + barycentric coordinates).

numpy only (a real Blender has no scipy): the exact query tests every triangle in blocks; the
approximate one tests only the triangles around each point's nearest vertices, which is what
alignment iterations need (tens of markers, thousands of triangles, many iterations).
"""

from dataclasses import dataclass

import numpy as np

from ..errors import FacecapError

#: Point-triangle pairs evaluated per block by the exact query (bounds the temporary memory).
BLOCK_PAIRS = 1 << 18
#: The approximate query looks at triangles within this share of the mesh's diagonal of the points' box.
NEAR_MARGIN = 0.1


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
        Triangle centroids (the approximate query's candidates).
    """

    vertices: np.ndarray
    triangles: np.ndarray
    normals: np.ndarray
    vertex_triangles: np.ndarray
    centroids: np.ndarray = None

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
    return Surface(vertices, tris, normals, _vertex_triangles(len(vertices), tris), centroids)


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


class NearCache:
    """Each point's ``k`` nearest triangle centroids, reused from call to call (ICP iterations move
    the points a little each time): ``spare`` x k candidates are kept per point, and a point's are
    searched again only when it has moved more than half the gap between its k-th and its last
    candidate's distance -- within that, its k nearest are among the kept ones, so the answer is
    the one a fresh query gives (up to rounding between centroids equally near at the k-th place).
    """

    def __init__(self, surface, k, spare=16):
        self.surface, self.k, self.big = surface, int(k), int(k) * int(spare)
        self.anchor = self.ids = self.slack = None

    def __call__(self, points):
        """(N, k) triangle ids of the centroids nearest each of ``points`` (N, 3)."""
        n = len(points)
        if self.anchor is None or len(self.anchor) != n:
            self.anchor, self.slack = np.full((n, 3), np.nan), np.full(n, -1.0)
            self.ids = np.zeros((n, min(self.big, len(self.surface.centroids))), dtype=np.int64)
        with np.errstate(invalid="ignore"):
            stale = ~(np.linalg.norm(points - self.anchor, axis=1) <= self.slack)
        if stale.any():
            ids, d2 = nearest_triangles(self.surface, points[stale], self.ids.shape[1], distances=True)
            k = min(self.k, ids.shape[1])
            self.ids[stale], self.anchor[stale] = ids, points[stale]
            self.slack[stale] = (np.sqrt(d2[:, -1]) - np.sqrt(d2[:, k - 1])) / 2
        k = min(self.k, self.ids.shape[1])
        d2 = np.sum((self.surface.centroids[self.ids] - points[:, None]) ** 2, axis=-1)
        near = np.argpartition(d2, k - 1, axis=1)[:, :k]
        return np.take_along_axis(self.ids, near, axis=1)


def closest_points(surface, points, *, candidates=None, cache=None):
    """Closest surface points to (N, 3) ``points``.

    Parameters
    ----------
    surface : Surface
    points : ndarray (N, 3)
    candidates : int or None
        None tests every triangle (exact); k tests the k triangles whose centroids are nearest
        each point (fast; exact unless the mesh mixes very large and small triangles there).
    cache : NearCache or None
        Gives the k nearest centroids instead (the same ones; cheaper for points that moved little).

    Returns
    -------
    triangle : ndarray (N,) int
    barycentric : ndarray (N, 3)
    closest : ndarray (N, 3)
    distance : ndarray (N,)
    """
    points = np.asarray(points, dtype=np.float64)
    if cache is not None:
        tri = cache(points)
    elif candidates is None:
        tri = _all_triangle_pairs(surface, points)
    else:
        tri = nearest_triangles(surface, points, candidates)
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
    """(N, k) ids of the triangles whose centroids are nearest each point (among those near the
    points' bounding box, when there are enough: a face's markers cover a part of a head); with
    ``distances``, sorted nearest first, with their (N, k) squared distances."""
    cen = surface.centroids
    ids = None
    lo, hi = points.min(axis=0), points.max(axis=0)
    margin = NEAR_MARGIN * np.linalg.norm(surface.vertices.max(axis=0) - surface.vertices.min(axis=0))
    inside = np.flatnonzero(((cen >= lo - margin) & (cen <= hi + margin)).all(axis=1))
    if len(inside) >= 4 * k:
        ids, cen = inside, cen[inside]
    d2 = squared_distances(points, cen)
    k = min(k, len(cen))
    near = np.argpartition(d2, k - 1, axis=1)[:, :k]
    if distances:
        d2 = np.take_along_axis(d2, near, axis=1)
        order = np.argsort(d2, axis=1)
        near, d2 = np.take_along_axis(near, order, axis=1), np.take_along_axis(d2, order, axis=1)
    found = near if ids is None else ids[near]
    return (found, d2) if distances else found


def squared_distances(a, b):
    """(..., N, P) squared distances between points a (..., N, 3) and b (P, 3) (|a|^2 - 2 a.b + |b|^2)."""
    return np.sum(a**2, axis=-1)[..., None] - 2.0 * (a @ b.T) + np.sum(b**2, axis=-1)


def _all_triangle_pairs(surface, points):
    """Exact query in blocks: the best triangle per point, as an (N, 1) array."""
    t = surface.n_triangles
    step = max(1, BLOCK_PAIRS // t)
    best = np.empty((len(points), 1), dtype=np.int64)
    all_tri = np.arange(t)
    for start in range(0, len(points), step):
        chunk = points[start:start + step]
        a, b, c = surface.corners(np.tile(all_tri, len(chunk)))
        p = np.repeat(chunk, t, axis=0)
        q, _ = closest_on_triangles(p, a, b, c)
        d2 = np.sum((p - q) ** 2, axis=1).reshape(len(chunk), t)
        best[start:start + step, 0] = np.argmin(d2, axis=1)
    return best


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


__all__ = ["NearCache", "Surface", "closest_on_triangles", "closest_points", "interpolate", "make_surface",
           "nearest_triangles", "squared_distances",
           "triangulate"]
