"""Closed-form rigid and similarity fits (weighted Kabsch / Umeyama), batched over frames."""

from dataclasses import dataclass

import numpy as np

from .errors import FacecapError


@dataclass(frozen=True, eq=False)
class Similarity:
    """x' = scale * R @ x + t."""

    scale: float
    rotation: np.ndarray  # (3, 3)
    translation: np.ndarray  # (3,)

    def apply(self, points):
        return self.scale * np.asarray(points) @ self.rotation.T + self.translation

    def apply_vectors(self, vectors):
        """Transform displacements (no translation)."""
        return self.scale * np.asarray(vectors) @ self.rotation.T

    def inverse_vectors(self, vectors):
        """Map displacements back (the inverse of :meth:`apply_vectors`)."""
        return np.asarray(vectors) @ self.rotation / self.scale


def fit_rigid_batch(source, target, weights):
    """Per-frame weighted rigid fit R_f, t_f minimising sum_i w_fi |R_f s_fi + t_f - y_fi|^2.

    Parameters
    ----------
    source : ndarray, shape (F, N, 3)
    target : ndarray, shape (N, 3) or (F, N, 3)
    weights : ndarray, shape (F, N)
        Non-negative; 0 for missing points (their coordinates are ignored, NaN allowed).

    Returns
    -------
    R : ndarray (F, 3, 3), proper rotations (det = +1, reflections corrected)
    t : ndarray (F, 3)
    rank_ok : ndarray (F,) bool
        False where fewer than 3 weighted points are present or they are (nearly) collinear,
        i.e. where the rotation is not determined by the data.
    """
    source = np.asarray(source, dtype=np.float64)
    w = np.asarray(weights, dtype=np.float64)
    target = np.asarray(target, dtype=np.float64)
    # A point with a non-finite coordinate in either set does not take part: weight 0, coordinates 0.
    # A shared (N, 3) target stays (N, 3): no (F, N, 3) copies of it.
    gap_src, gap_tgt = gap_mask(source), gap_mask(target)
    w = np.where(gap_src | gap_tgt, 0.0, w)
    src = zero_rows(source, gap_src)
    return fit_rigid_masked(src, zero_rows(target, gap_tgt), w, overwrite=src is not source)


def fit_rigid_masked(src, tgt, w, *, overwrite=False):
    """:func:`fit_rigid_batch` for finite ``src``/``tgt`` and weights already 0 at their gaps.

    ``overwrite``: ``src`` is a scratch copy the caller gives up; centring it in place saves an
    (F, N, 3) temporary (on long takes the allocation and its page faults cost as much as the pass).
    """
    wsum = w.sum(axis=1)
    safe = np.where(wsum > 0, wsum, 1.0)
    # Batched matmuls, not einsum: three-operand einsum is ~10x slower on long takes.
    cs = (w[:, None, :] @ src)[:, 0] / safe[:, None]
    ct = (w @ tgt if tgt.ndim == 2 else (w[:, None, :] @ tgt)[:, 0]) / safe[:, None]
    s0 = np.subtract(src, cs[:, None], out=src if overwrite else None)
    ws0 = s0 * w[:, :, None]
    # sum w s0 (t - ct)' = sum w s0 t' since sum w s0 = 0: the target needs no centring
    H = ws0.transpose(0, 2, 1) @ tgt
    R = best_rotation(H)
    t = ct - (R @ cs[:, :, None])[:, :, 0]

    # Spread of the source points: rotation is determined only with >= 3 non-collinear points.
    cov = (ws0.transpose(0, 2, 1) @ s0) / safe[:, None, None]
    count = (w > 0).sum(axis=1)
    rank_ok = (count >= 3) & _spread_ok(cov)
    return R, t, rank_ok


def gap_mask(points):
    """(..., N) bool: points with a NaN or infinite coordinate (one pass: a NaN or inf poisons the sum)."""
    total = points[..., 0] + points[..., 1]
    total += points[..., 2]
    return ~np.isfinite(total)


def zero_rows(points, gap):
    """``points`` with the ``gap`` rows set to 0 (a copy only when there is a gap)."""
    if not gap.any():
        return points
    out = points.copy()
    out[gap] = 0.0
    return out


def _spread_ok(cov, ratio=1e-3):
    """(F,) bool: the middle singular value of the spread exceeds ``ratio`` x the largest (not collinear).

    ``cov`` (F, 3, 3) is symmetric positive semi-definite with eigenvalues a <= b <= c; the test is
    b > ratio^2 c. Cheap invariants bound b / c (bc <= e2 <= 3bc for e2 = ab + ac + bc, and
    e1 / 3 <= c <= e1 for the trace e1) so ~every frame is decided without an eigen-solve; only
    frames within a factor ~30 of the threshold take ``eigvalsh``, as every frame used to.
    """
    c = cov.reshape(-1, 9).T
    e1 = c[0] + c[4] + c[8]
    e2 = c[0] * c[4] - c[3] * c[3] + c[0] * c[8] - c[6] * c[6] + c[4] * c[8] - c[7] * c[7]
    limit = ratio**2 * e1 * e1
    ok = e2 > 6.0 * limit  # b / c >= e2 / (3 e1^2) > ratio^2, with a factor 2 to spare for rounding
    unsure = ~ok & ~(18.0 * e2 < limit)  # b / c <= 9 e2 / e1^2 < ratio^2 (same margin)
    if unsure.any():
        sv = np.sqrt(np.clip(np.linalg.eigvalsh(cov[unsure]), 0.0, None))  # ascending
        ok[unsure] = sv[:, 1] > ratio * np.maximum(sv[:, 2], 1e-300)
    return ok


#: Frames whose quaternion eigenvalue gap is below this (relative) bound take the SVD path.
_MIN_GAP = 1e-2
#: Cross-covariances larger (or smaller) than this are scaled to unit size first: the closed form raises
#: them to the 4th power, which overflows (or underflows) the float range beyond it.
_SAFE_SCALE = 1e50


def best_rotation(H):
    """Proper rotations R_f maximising trace(R_f @ H_f), for H of shape (F, 3, 3).

    With H = sum_i w_i s_i y_i^T this is the Kabsch rotation taking the points s onto y; with
    H = X^T it is the rotation nearest to X. Same answer as the SVD solution
    V diag(1, 1, det(V U^T)) U^T of H = U S V^T, ~6x faster than the batched SVD: the rotation's
    quaternion is the top eigenvector of Horn's symmetric 4x4 matrix, whose eigenvalue is found
    by Newton's method on the characteristic polynomial (Theobald's QCP) and whose eigenvector
    is a column of the adjugate. Where the top eigenvalue is (nearly) double the rotation is not
    well determined (collinear points, or a reflection with sigma_2 ~ sigma_3) and the
    closed form loses precision, so those frames take the SVD.
    """
    H = np.asarray(H, dtype=np.float64)
    F = H.shape[0]
    if not np.isfinite(H).all():
        raise FacecapError("best_rotation: the point sets' cross-covariance is not finite (coordinates beyond "
                           "the float range, or NaN points)")
    size = np.abs(H).reshape(F, 9).max(axis=1) if F else np.zeros(0)
    extreme = (size > _SAFE_SCALE) | ((size < 1.0 / _SAFE_SCALE) & (size > 0))
    if extreme.any():  # the polynomial has H to the 4th power: bring such frames to unit size (R is the same)
        H = H.copy()
        H[extreme] /= size[extreme, None, None]
    sxx, sxy, sxz, syx, syy, syz, szx, szy, szz = np.ascontiguousarray(H.reshape(F, 9).T)
    N = np.array([
        [sxx + syy + szz, syz - szy, szx - sxz, sxy - syx],
        [syz - szy, sxx - syy - szz, sxy + syx, szx + sxz],
        [szx - sxz, sxy + syx, syy - sxx - szz, syz + szy],
        [sxy - syx, szx + sxz, syz + szy, szz - sxx - syy],
    ])  # (4, 4, F)
    # Characteristic polynomial lam^4 + c2 lam^2 + c1 lam + c0 (N is traceless).
    norm2 = sxx * sxx + sxy * sxy + sxz * sxz + syx * syx + syy * syy + syz * syz + szx * szx + szy * szy + szz * szz
    c2 = -2.0 * norm2
    c1 = -8.0 * _det3(((sxx, sxy, sxz), (syx, syy, syz), (szx, szy, szz)))
    c0 = _det4(N)
    # Newton from above the top root (sigma_1 + sigma_2 + sigma_3 <= sqrt(3) |H|) descends
    # monotonically onto it: every root is real, so the polynomial is convex beyond the top one.
    scale = np.sqrt(norm2)
    lam = np.sqrt(3.0) * scale
    for _ in range(60):
        lam2 = lam * lam
        p = ((lam2 + c2) * lam + c1) * lam + c0
        dp = (4.0 * lam2 + 2.0 * c2) * lam + c1
        step = np.divide(p, dp, out=np.zeros(F), where=dp > 0)
        lam -= step
        # The slope only shrinks on the way down: a frame whose slope is already below the gap
        # bound will take the SVD and need not converge here.
        closed = dp > _MIN_GAP * scale**3
        if not (np.abs(step[closed]) > 1e-13 * scale[closed]).any():
            break
    # P'(lam_1) = product of the gaps to the other three eigenvalues, each <= 2 sqrt(3) |H|.
    dp = (4.0 * lam * lam + 2.0 * c2) * lam + c1
    closed = dp > _MIN_GAP * scale**3
    for k in range(4):
        N[k, k] -= lam
    adj = _adjugate4(N)  # ~ P'(lam_1) q q^T: its largest diagonal entry marks the best column
    k = np.argmax(np.abs(adj[np.arange(4), np.arange(4)]), axis=0)
    w, x, y, z = adj[k, :, np.arange(F)].T
    n = w * w + x * x + y * y + z * z
    n[~closed] = 1.0  # may be 0 there (no points at all); those frames are replaced below
    R = np.stack([
        w * w + x * x - y * y - z * z, 2.0 * (x * y - w * z), 2.0 * (x * z + w * y),
        2.0 * (x * y + w * z), w * w - x * x + y * y - z * z, 2.0 * (y * z - w * x),
        2.0 * (x * z - w * y), 2.0 * (y * z + w * x), w * w - x * x - y * y + z * z,
    ], axis=1).reshape(F, 3, 3) / n[:, None, None]
    if not closed.all():
        R[~closed] = _rotation_svd(H[~closed])
    return R


def _rotation_svd(H):
    """:func:`best_rotation` by SVD (Kabsch with the reflection corrected)."""
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(Vt.transpose(0, 2, 1) @ U.transpose(0, 2, 1)))
    d = np.where(d == 0, 1.0, d)
    D = np.broadcast_to(np.eye(3), H.shape).copy()
    D[:, 2, 2] = d
    return Vt.transpose(0, 2, 1) @ D @ U.transpose(0, 2, 1)


def _det3(m):
    """Determinant of 3x3 matrices given as nested rows of equal-shape arrays."""
    return (m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
            - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]))


def _det4(a):
    """Determinant of (4, 4, F) matrices, expanded along the first row."""
    return sum((-1) ** j * a[0, j] * _det3(_minor(a, 0, j)) for j in range(4))


def _adjugate4(a):
    """Adjugate of symmetric (4, 4, F) matrices (symmetric too: ten cofactors)."""
    out = np.empty_like(a)
    for i in range(4):
        for j in range(i, 4):
            out[i, j] = out[j, i] = (-1) ** (i + j) * _det3(_minor(a, i, j))
    return out


def _minor(a, i, j):
    rows = [r for r in range(4) if r != i]
    cols = [c for c in range(4) if c != j]
    return [[a[r, c] for c in cols] for r in rows]


def fit_similarity(source, target, weights=None, *, allow_scale=True):
    """Weighted similarity (Umeyama) from ``source`` (N, 3) to ``target`` (N, 3).

    Returns
    -------
    Similarity
    """
    source = np.asarray(source, dtype=np.float64)
    target = np.asarray(target, dtype=np.float64)
    if source.shape != target.shape or source.ndim != 2 or source.shape[1] != 3:
        raise FacecapError(f"similarity fit needs two (N, 3) arrays; got {source.shape} and {target.shape}")
    w = np.ones(len(source)) if weights is None else np.asarray(weights, dtype=np.float64)
    ok = np.isfinite(source).all(axis=1) & np.isfinite(target).all(axis=1) & (w > 0)
    if ok.sum() < 3:
        raise FacecapError(f"similarity fit needs at least 3 corresponding points; got {int(ok.sum())}")
    R, t, rank_ok = fit_rigid_batch(source[None], target[None], (w * ok)[None])
    if not rank_ok[0]:
        raise FacecapError("similarity fit: the corresponding points are (nearly) collinear")
    R = R[0]
    wn = (w * ok) / (w * ok).sum()
    src = np.where(ok[:, None], source, 0.0)
    tgt = np.where(ok[:, None], target, 0.0)
    cs = wn @ src
    ct = wn @ tgt
    s0 = src - cs
    t0 = tgt - ct
    scale = 1.0
    if allow_scale:
        var_s = float(np.sum(wn[:, None] * s0**2))
        scale = float(np.sum(wn[:, None] * (t0 @ R) * s0)) / var_s
    return Similarity(scale=scale, rotation=R, translation=ct - scale * R @ cs)


def rotation_angle_deg(R):
    """Rotation angle(s) in degrees of rotation matrices (..., 3, 3)."""
    R = np.asarray(R)
    cos = (np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0
    axis = np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], axis=-1)
    sin = np.linalg.norm(axis, axis=-1) / 2.0
    return np.degrees(np.arctan2(sin, cos))  # accurate near 0, unlike arccos


def matrix_to_euler_xyz(R):
    """Blender 'XYZ' Euler angles (radians) of rotation matrices (..., 3, 3): R = Rz @ Ry @ Rx."""
    R = np.asarray(R)
    a = np.arctan2(R[..., 2, 1], R[..., 2, 2])
    b = np.arctan2(-R[..., 2, 0], np.hypot(R[..., 2, 1], R[..., 2, 2]))
    c = np.arctan2(R[..., 1, 0], R[..., 0, 0])
    return np.stack([a, b, c], axis=-1)


def fit_similarity_2d(source, target):
    """Similarity (scale, proper rotation, translation) from 2D points ``source`` (N, 2) to ``target`` (N, 2).

    Points with a NaN in either set are ignored. Returns a :class:`Similarity` with a 2x2 rotation.
    """
    source = np.asarray(source, dtype=np.float64)
    target = np.asarray(target, dtype=np.float64)
    ok = np.isfinite(source).all(axis=1) & np.isfinite(target).all(axis=1)
    if ok.sum() < 2:
        raise FacecapError(f"2D similarity fit needs at least 2 corresponding points; got {int(ok.sum())}")
    src, tgt = source[ok], target[ok]
    cs, ct = src.mean(axis=0), tgt.mean(axis=0)
    s0, t0 = src - cs, tgt - ct
    U, S, Vt = np.linalg.svd(t0.T @ s0)
    d = np.sign(np.linalg.det(U @ Vt)) or 1.0
    R = U @ np.diag([1.0, d]) @ Vt
    var = float((s0**2).sum())
    if var <= 0:
        raise FacecapError("2D similarity fit: the source points coincide")
    scale = float((S * [1.0, d]).sum() / var)
    return Similarity(scale=scale, rotation=R, translation=ct - scale * R @ cs)
