"""Similarity alignment of a marker cloud to a surface: landmarks, robust ICP, multi-start search.

All residuals are point-to-plane distances in millimetres (``unit`` = one millimetre in mesh
units) with Cauchy weights, solved by Gauss-Newton over (rotation, translation, log scale). The
scale only moves within SCALE_RANGE of where it starts: a surface alone does not fix it (a cloud
shrunk onto a small patch always fits), so it comes from the landmarks or, automatically, from
SEARCH_SCALES around the same-size guess. Landmarks start the alignment; the surface decides
(an actor's proportions differ from a character's, so marker -> vertex pairs are approximate).
numpy only (small systems solved by :func:`solve_spd`).
"""

import numpy as np

from ..errors import FacecapError
from ..transforms import Similarity, fit_similarity, rotation_angle_deg
from .surface import closest_points, smooth_normals

#: Cauchy weight scale (times the residuals' robust sigma) and the sigma's floor, mm.
CAUCHY = 2.385
SIGMA_FLOOR_MM = 0.5
#: The refinement's steps that re-estimate the robust sigma (then it stays and the cost must fall) and how often a
#: step that does not lower the cost is halved before the refinement stops.
ADAPT, HALVINGS = 3, 8
#: Standard deviation of log(scale) around its starting value (a weak prior) and the factor the
#: refinement may move the scale by at most.
SCALE_PRIOR = np.log(1.5)
SCALE_RANGE = 1.15
#: Scales the automatic search's coarse stage tries, relative to the expected one (same-size
#: faces), and the range its finalists' refinement may move the scale in.
SEARCH_SCALES = (0.8, 1.0, 1.25)
SEARCH_SCALE_RANGE = 1.15
#: Automatic search: directions on a sphere x roll angles, coarse iterations, refined finalists.
DIRECTIONS, ROLLS, COARSE_ITERATIONS, FINALISTS = 32, 8, 4, 10
#: Surface samples of the coarse search (triangle centroids, evenly strided).
COARSE_SAMPLES = 600
#: Triangles tested per marker in the iterations (those with the nearest centroids).
CANDIDATES = 16
#: Share of markers the score keeps (the rest may be off the surface: head bands, stray markers).
TRIM = 0.8
#: Two poses are different when their rotations differ by more than this (degrees) ...
DISTINCT_DEG = 10.0
#: A best automatic pose farther than this (trimmed RMS, mm) from the surface is no fit at all (wrong units,
#: not a face): refused. Real captures fit to 0.3-2.5 mm (Facial-Sing with its head markers: 2.1 mm).
NO_FIT_MM = 6.0
#: ... and ambiguous when their mean squared distances (plus FLOOR_MM^2, below which distances are
#: noise) are in a ratio below 1 + 3 / sqrt(n) for n scored markers: within about 1.5 standard
#: deviations of the ratio of two sums of n squared errors (2 / sqrt(n)).
FLOOR_MM = 0.1


def ambiguous(best, second, n):
    """Whether trimmed RMS distances ``best`` <= ``second`` (mm) of n markers cannot tell two poses apart."""
    return (second**2 + FLOOR_MM**2) / (best**2 + FLOOR_MM**2) < 1.0 + 3.0 / np.sqrt(n)


def align_landmarks(pairs, *, allow_scale=True):
    """Similarity from landmark pairs (rows, actor (L, 3), character (L, 3)); refuses collinear ones."""
    _, src, dst = pairs
    try:
        return fit_similarity(src, dst, allow_scale=allow_scale)
    except FacecapError as exc:
        raise FacecapError(f"landmarks: {str(exc).split(': ', 1)[-1]}; choose landmarks spread over the face "
                           "(e.g. both eye corners and the chin)") from None


def _skew(v):
    """(..., 3) -> (..., 3, 3) cross-product matrices."""
    z = np.zeros_like(v[..., 0])
    return np.stack([np.stack([z, -v[..., 2], v[..., 1]], -1), np.stack([v[..., 2], z, -v[..., 0]], -1),
                     np.stack([-v[..., 1], v[..., 0], z], -1)], -2)


def rodrigues(w):
    """Rotation matrices (..., 3, 3) for rotation vectors (..., 3)."""
    theta = np.linalg.norm(w, axis=-1)[..., None, None]
    k = _skew(w)
    with np.errstate(invalid="ignore", divide="ignore"):
        a = np.where(theta > 1e-12, np.sin(theta) / theta, 1.0)
        b = np.where(theta > 1e-12, (1 - np.cos(theta)) / theta**2, 0.5)
    return np.eye(3) + a * k + b * (k @ k)


def _weights(r):
    """Cauchy weights of residuals r (..., M) in mm, with a robust sigma per leading index."""
    sigma = np.maximum(1.4826 * np.median(np.abs(r), axis=-1, keepdims=True), SIGMA_FLOOR_MM)
    return 1.0 / (1.0 + (r / (CAUCHY * sigma)) ** 2)


def _step(srp, n, r, w, log_s, log_s0, allow_scale):
    """Gauss-Newton step (..., 7) = (rotation vector, translation in mm, log scale) for point-to-plane
    residuals r (..., M) in mm, normals n (..., M, 3), scaled rotated points srp (..., M, 3) in mm."""
    J = np.concatenate([np.cross(srp, n), n, np.sum(n * srp, axis=-1, keepdims=True)], axis=-1)
    JW = J * w[..., None]
    A = np.swapaxes(JW, -1, -2) @ J
    g = np.swapaxes(JW, -1, -2) @ r[..., None]
    prior = 1.0 / SCALE_PRIOR**2
    A[..., 6, 6] += prior
    g[..., 6, 0] += prior * (log_s - log_s0)
    if not allow_scale:
        A[..., 6, :] = 0.0
        A[..., :, 6] = 0.0
        A[..., 6, 6] = 1.0
        g[..., 6, 0] = 0.0
    A = A + 1e-9 * np.trace(A, axis1=-2, axis2=-1)[..., None, None] * np.eye(7)
    return -solve_spd(A, g)[..., 0]


def solve_spd(A, b):
    """Solve batched small symmetric positive definite systems A (..., n, n) x = b (..., n, k) by
    Gaussian elimination without pivoting, in numpy: LAPACK's threaded call costs far more than
    the arithmetic of a 7 x 7 system, above all on a busy machine."""
    A = np.array(A, dtype=np.float64)
    b = np.array(b, dtype=np.float64)
    n = A.shape[-1]
    for i in range(n):
        f = A[..., i + 1:, i] / A[..., i:i + 1, i]
        A[..., i + 1:, :] -= f[..., None] * A[..., i:i + 1, :]
        b[..., i + 1:, :] -= f[..., None] * b[..., i:i + 1, :]
    x = np.empty_like(b)
    for i in range(n - 1, -1, -1):
        x[..., i, :] = (b[..., i, :] - np.einsum("...j,...jk->...k", A[..., i, i + 1:], x[..., i + 1:, :])) / A[..., i, i:i + 1]
    return x


def _cost(r, sigma, log_s, log_s0, allow_scale):
    """The robust cost the refinement lowers: Cauchy losses of residuals ``r`` (mm) at the robust ``sigma``, and
    the scale's prior."""
    c = CAUCHY * sigma
    cost = 0.5 * c**2 * np.log1p((r / c) ** 2).sum()
    return cost + (0.5 * ((log_s - log_s0) / SCALE_PRIOR) ** 2 if allow_scale else 0.0)


def refine(surface, markers, start, *, unit, allow_scale=True, iterations=60, scale_range=SCALE_RANGE):
    """Robust point-to-plane ICP of (M, 3) ``markers`` onto ``surface`` from Similarity ``start``.

    The scale stays within ``start.scale`` divided or multiplied by ``scale_range``: a surface alone
    does not fix it (a cloud shrunk onto a small patch always fits), only near the right one. The robust
    weights' scale follows the residuals for ``ADAPT`` steps, then stays, and from there a step is kept only when
    it lowers the robust cost (halved until it does): the refinement settles in a minimum instead of wandering
    between closest points until the step cap, where it stopped at a pose the numeric library's rounding chose.

    Returns (Similarity, a one-line note with iterations, the median distance and the scale).
    """
    c = markers.mean(axis=0)
    pc = markers - c
    R, s, t = start.rotation.copy(), float(start.scale), start.apply(c)
    log_s0 = np.log(s)
    lo, hi = log_s0 - np.log(scale_range), log_s0 + np.log(scale_range)

    def residuals(R, s, t):
        srp = s * pc @ R.T
        x = srp + t
        tri, bary, q, _ = closest_points(surface, x, candidates=CANDIDATES)
        n = smooth_normals(surface.vertex_normals, surface.triangles, tri, bary)  # no jump from triangle to triangle
        return srp, n, np.sum(n * (x - q), axis=1) / unit

    sigma = None
    srp, n, r = residuals(R, s, t)
    for it in range(1, iterations + 1):
        if it <= ADAPT or sigma is None:
            sigma = max(1.4826 * float(np.median(np.abs(r))), SIGMA_FLOOR_MM)
        w = 1.0 / (1.0 + (r / (CAUCHY * sigma)) ** 2)
        delta = _step(srp / unit, n, r, w, np.log(s), log_s0, allow_scale)
        if allow_scale and not lo <= np.log(s) + delta[6] <= hi:  # the scale goes to its bound, the rest without it
            wanted = np.log(s) + delta[6]
            delta = _step(srp / unit, n, r, w, np.log(s), log_s0, False)
            delta[6] = np.clip(wanted, lo, hi) - np.log(s)
        before = _cost(r, sigma, np.log(s), log_s0, allow_scale)
        for _ in range(HALVINGS + 1):
            R1, t1 = rodrigues(delta[:3]) @ R, t + delta[3:6] * unit
            s1 = float(np.exp(np.clip(np.log(s) + delta[6], lo, hi)))
            srp1, n1, r1 = residuals(R1, s1, t1)
            if it <= ADAPT or _cost(r1, sigma, np.log(s1), log_s0, allow_scale) <= before:
                break
            delta = 0.5 * delta
        else:
            break  # no step lowers the cost: a minimum
        R, s, t, srp, n, r = R1, s1, t1, srp1, n1, r1
        if np.abs(delta[:3]).max() < 1e-4 and np.abs(delta[3:6]).max() < 1e-2 and abs(delta[6]) < 1e-4:
            break  # every marker moved by less than ~0.01 mm (a face is ~0.1 m across)
    sim = Similarity(scale=s, rotation=R, translation=t - s * R @ c)
    d = closest_points(surface, sim.apply(markers), candidates=CANDIDATES)[3] / unit
    at_bound = allow_scale and abs(abs(np.log(s) - log_s0) - np.log(scale_range)) < 1e-9
    return sim, (f"ICP: {it} iterations, median distance {np.median(d):.2f} mm, "
                 f"{int(np.sum(d > 3 * max(np.median(d), SIGMA_FLOOR_MM)))} marker(s) off the surface"
                 + (f"; the scale stopped at its bound ({scale_range:g}x the start)" if at_bound else ""))


def score(surface, sim, markers, unit):
    """Trimmed RMS distance (mm) of the best TRIM share of aligned markers to the surface."""
    d = np.sort(closest_points(surface, sim.apply(markers), candidates=CANDIDATES)[3] / unit)
    keep = max(3, int(np.ceil(TRIM * len(d))))
    return float(np.sqrt(np.mean(d[:keep] ** 2)))


def _fibonacci(n):
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    r = np.sqrt(1 - z**2)
    phi = np.pi * (1 + 5**0.5) * i
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def hypotheses(markers):
    """(H, 3, 3) rotations taking the cloud's principal frame to DIRECTIONS x ROLLS frames."""
    pc = markers - markers.mean(axis=0)
    _, vecs = np.linalg.eigh(pc.T @ pc)
    frame = vecs[:, ::-1]  # e1 (widest), e2, e3 (the cloud's normal)
    if np.linalg.det(frame) < 0:
        frame[:, 2] *= -1
    out = []
    for d in _fibonacci(DIRECTIONS):
        u = np.cross(d, [0.0, 0.0, 1.0] if abs(d[2]) < 0.9 else [1.0, 0.0, 0.0])
        u /= np.linalg.norm(u)
        v = np.cross(d, u)
        for a in np.arange(ROLLS) * 2 * np.pi / ROLLS:
            g = np.stack([np.cos(a) * u + np.sin(a) * v, -np.sin(a) * u + np.cos(a) * v, d], axis=1)
            out.append(g @ frame.T)
    return np.asarray(out)


def _coarse(surface, pc, R, s, t, unit):
    """A few batched point-to-plane iterations against the surface's sample; returns (R, s, t, trimmed RMS mm)."""
    tri = np.linspace(0, surface.n_triangles - 1, min(COARSE_SAMPLES, surface.n_triangles)).astype(int)
    sample = surface.vertices[surface.triangles[tri]].mean(axis=1)
    normals = surface.normals[tri]
    from scipy.spatial import cKDTree  # scipy: loaded when a character is first bound, not with the package

    tree = cKDTree(sample)
    log_s0 = np.log(s)
    for _ in range(COARSE_ITERATIONS + 1):
        srp = s[:, None, None] * pc @ np.swapaxes(R, 1, 2)
        x = srp + t[:, None]
        dist, near = tree.query(x.reshape(-1, 3))
        dist, near = dist.reshape(x.shape[:2]) / unit, near.reshape(x.shape[:2])
        n = normals[near]
        r = np.sum(n * (x - sample[near]), -1) / unit
        delta = _step(srp / unit, n, r, _weights(r), np.log(s), log_s0, False)  # scale held: no collapse
        R = rodrigues(delta[:, :3]) @ R
        t = t + delta[:, 3:6] * unit
    keep = max(3, int(np.ceil(TRIM * pc.shape[0])))
    return R, s, t, np.sqrt(np.mean(np.sort(dist, axis=1)[:, :keep] ** 2, axis=1))


def align_automatic(surface, markers, *, unit, scale, allow_scale=True, chunk=48):
    """Multi-start alignment of (M, 3) markers to the surface without landmarks (:func:`automatic_poses`):
    the pose that fits best. Raises FacecapError when none fits (NO_FIT_MM) or when a different pose
    (rotated by more than DISTINCT_DEG) scores almost as well as the best (:func:`ambiguous`).

    Returns (Similarity, a one-line note).
    """
    results, h = automatic_poses(surface, markers, unit=unit, scale=scale, allow_scale=allow_scale, chunk=chunk)
    best, sim = results[0]
    second = next(((sc, other) for sc, other in results[1:]
                   if rotation_angle_deg(other.rotation @ sim.rotation.T) > DISTINCT_DEG), None)
    kept = max(3, int(np.ceil(TRIM * len(markers))))
    if best > NO_FIT_MM:
        raise FacecapError(
            f"automatic binding found no pose that fits: the best leaves the markers {best:.1f} mm from the surface "
            f"(trimmed RMS) at {sim.scale / scale:.2f}x the same-size scale; are the markers' units right, and is the "
            "mesh a face? Give at least three landmarks in [binding.landmarks] (marker = a vertex group or vertex "
            "index of the character), e.g. the markers on the nose tip, the chin and an outer eye corner")
    if second is not None and ambiguous(best, second[0], kept):
        angle = float(rotation_angle_deg(second[1].rotation @ sim.rotation.T))
        raise FacecapError(
            f"automatic binding is ambiguous: two poses {angle:.0f} deg apart fit the markers almost equally well "
            f"(trimmed RMS distance {best:.2f} mm and {second[0]:.2f} mm); give at least three landmarks "
            "(marker -> vertex) to say which")
    note = (f"automatic alignment: {h} starting rotations, best trimmed RMS distance {best:.2f} mm"
            + (f", next distinct pose {second[0]:.2f} mm" if second is not None else ""))
    return sim, note


def automatic_poses(surface, markers, *, unit, scale, allow_scale=True, chunk=48):
    """The automatic search's poses of (M, 3) markers on the surface, best first.

    Every rotation of :func:`hypotheses`, the cloud's most protruding marker touching the
    surface's farthest point in that direction, is refined coarsely at each of SEARCH_SCALES; the
    best distinct rotations (FINALISTS in all) are refined and scored (:func:`score`).

    Returns ([(trimmed RMS distance mm, Similarity)] sorted by distance, the number of starting rotations).
    """
    if len(markers) < 4:
        raise FacecapError(f"automatic binding needs at least 4 markers with a neutral position; got {len(markers)}")
    c = markers.mean(axis=0)
    pc = markers - c
    Rs = np.repeat(hypotheses(markers), len(SEARCH_SCALES), axis=0)
    scales = np.tile(np.asarray(SEARCH_SCALES) * scale, len(Rs) // len(SEARCH_SCALES))
    h = len(Rs)
    centre = surface.vertices.mean(axis=0)
    normal = _cloud_normal(pc)
    out_R, out_s, out_t, out_score = [], [], [], []
    for a in range(0, h, chunk):
        R = Rs[a:a + chunk]
        dirs = R @ normal  # where each hypothesis points the cloud's normal
        sc_ = scales[a:a + chunk]
        top = np.max(sc_[:, None, None] * np.einsum("hij,mj->hmi", R, pc) @ dirs[..., None], axis=(1, 2))
        far = np.max((surface.vertices - centre) @ dirs.T, axis=0)
        t = centre + (far - top)[:, None] * dirs  # the most protruding marker touches the surface
        r_, s_, t_, sc = _coarse(surface, pc, R.copy(), sc_.copy(), t, unit)
        out_R.append(r_)
        out_s.append(s_)
        out_t.append(t_)
        out_score.append(sc)
    R, S, T, coarse = (np.concatenate(x) for x in (out_R, out_s, out_t, out_score))
    ok = np.isfinite(coarse) & np.isfinite(S) & (S > 0)
    order = [i for i in np.argsort(np.where(ok, coarse, np.inf)) if ok[i]]
    finalists = []
    for k in range(len(SEARCH_SCALES)):  # the best distinct rotations at each starting scale
        mine = []
        for i in (i for i in order if i % len(SEARCH_SCALES) == k):
            if all(rotation_angle_deg(R[i] @ R[j].T) > DISTINCT_DEG for j in mine):
                mine.append(i)
            if len(mine) == -(-FINALISTS // len(SEARCH_SCALES)):
                break
        finalists += mine
    results = []
    for i in finalists:
        start = Similarity(scale=float(S[i]), rotation=R[i], translation=T[i] - S[i] * R[i] @ c)
        sim, _ = refine(surface, markers, start, unit=unit, allow_scale=allow_scale, iterations=30,
                        scale_range=SEARCH_SCALE_RANGE)
        results.append((score(surface, sim, markers, unit), sim))
    results.sort(key=lambda x: x[0])
    return results, h


def _cloud_normal(pc):
    _, vecs = np.linalg.eigh(pc.T @ pc)
    frame = vecs[:, ::-1]
    if np.linalg.det(frame) < 0:
        frame[:, 2] *= -1
    return frame[:, 2]


__all__ = ["align_automatic", "align_landmarks", "ambiguous", "automatic_poses", "hypotheses", "refine", "rodrigues", "score", "solve_spd"]
