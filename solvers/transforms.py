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
    # A shared (N, 3) target stays (N, 3): no (F, N, 3) copies of it.
    w = np.where(np.isnan(source).any(axis=2) | np.isnan(target).any(axis=-1), 0.0, w)
    src = np.nan_to_num(source)
    tgt = np.nan_to_num(target)
    wsum = w.sum(axis=1)
    safe = np.where(wsum > 0, wsum, 1.0)
    # Batched matmuls, not einsum: three-operand einsum is ~10x slower on long takes.
    cs = (w[:, None, :] @ src)[:, 0] / safe[:, None]
    ct = (w @ tgt if tgt.ndim == 2 else (w[:, None, :] @ tgt)[:, 0]) / safe[:, None]
    s0 = src - cs[:, None]
    ws0 = s0 * w[:, :, None]
    # sum w s0 (t - ct)' = sum w s0 t' since sum w s0 = 0: the target needs no centring
    H = ws0.transpose(0, 2, 1) @ tgt
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(Vt.transpose(0, 2, 1) @ U.transpose(0, 2, 1)))
    d = np.where(d == 0, 1.0, d)
    D = np.broadcast_to(np.eye(3), H.shape).copy()
    D[:, 2, 2] = d
    R = Vt.transpose(0, 2, 1) @ D @ U.transpose(0, 2, 1)
    t = ct - (R @ cs[:, :, None])[:, :, 0]

    # Spread of the source points: rotation is determined only with >= 3 non-collinear points.
    cov = (ws0.transpose(0, 2, 1) @ s0) / safe[:, None, None]
    sv = np.sqrt(np.clip(np.linalg.eigvalsh(cov), 0.0, None))  # ascending
    count = (w > 0).sum(axis=1)
    rank_ok = (count >= 3) & (sv[:, 1] > 1e-3 * np.maximum(sv[:, 2], 1e-300))
    return R, t, rank_ok


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
