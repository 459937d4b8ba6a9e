"""Low-rank maths the strategies share: PCA (with gaps, by soft-impute) and filling marker gaps
through a linear subspace."""

import numpy as np

from ..errors import FacecapError


def fill_gaps(X, mean, components):
    """Fill NaN entries of X (F, P) from the visible ones through a linear subspace.

    For every frame with gaps, solve for subspace coefficients on the visible coordinates (least
    squares) and take the missing ones from the reconstruction (the PPCA-style imputation of the
    retargeting course, section 2). ``components`` (C, P) with orthonormal rows; ``mean`` (P,).
    Frames with no visible coordinate stay NaN. Returns (filled X, frames that had gaps).

    With k coordinates missing (A = components[:, missing], (C, k)) the normal equations of the
    visible ones are (I - A A') c = components[:, visible] x_visible, solved by Woodbury through the
    k x k matrix I - A'A: no least-squares solve over the C components per frame (a 2,000-frame
    take with 5% gaps and ~160 components: 0.15 s instead of 3.4 s). Frames whose visible
    coordinates hardly determine the coefficients (I - A'A nearly singular) take the minimum-norm
    least squares.
    """
    X = np.array(X, dtype=np.float64)
    gaps = np.isnan(X)
    rows = np.flatnonzero(gaps.any(axis=1))
    for f in rows:
        miss = gaps[f]
        if miss.all():
            continue
        vis = ~miss
        A = components[:, miss]
        S = np.eye(A.shape[1]) - A.T @ A
        if np.linalg.eigvalsh(S)[0] >= 1e-6:
            b = components[:, vis] @ (X[f, vis] - mean[vis])
            coef = b + A @ np.linalg.solve(S, A.T @ b)
        else:
            coef, *_ = np.linalg.lstsq(components[:, vis].T, X[f, vis] - mean[vis], rcond=None)
        X[f, miss] = mean[miss] + coef @ A
    return X, rows


def pca(X, *, center=True, n_components=None, variance=None):
    """Principal components of X (N, P) by SVD.

    Returns mean (P,) (zeros if not ``center``), components (C, P) orthonormal rows in
    descending variance with the largest-magnitude entry positive, singular values (C,), and
    the explained variance ratio (C,). ``n_components`` caps C; ``variance`` (0-1] keeps the
    fewest components reaching that share of the total. Components with a singular value below
    1e-10 of the largest are dropped (rank).
    """
    X = np.asarray(X, dtype=np.float64)
    mean = X.mean(axis=0) if center else np.zeros(X.shape[1])
    U, s, Vt = np.linalg.svd(X - mean, full_matrices=False)
    rank = int(np.sum(s > 1e-10 * (s[0] if s.size and s[0] > 0 else 1.0)))
    energy = s**2 / max(np.sum(s**2), 1e-300)
    C = rank
    if variance is not None:
        C = min(C, int(np.searchsorted(np.cumsum(energy), variance - 1e-12) + 1))
    if n_components is not None:
        C = min(C, int(n_components))
    Vt = Vt[:C]
    signs = np.sign(Vt[np.arange(C), np.argmax(np.abs(Vt), axis=1)])
    signs[signs == 0] = 1.0
    return mean, Vt * signs[:, None], s[:C], energy[:C]


def pca_gappy(X, *, center=True, n_components=None, variance=None, tol=1e-4, max_iterations=100,
              start_components=60, max_rows=2000):
    """``pca`` of X (N, P) with NaN gaps, every row with a visible entry contributing.

    With markers occluded independently, most frames of a take have some gap and the gap-free ones
    may be little more than the neutral holds: a PCA of those spans noise, not the performance.
    Here the missing entries are imputed by soft-thresholded SVD (soft-impute, Mazumder et al.
    2010) with the threshold at the noise level of Gavish & Donoho's optimal hard threshold, so no
    rank has to be chosen and weak (noise) directions do not absorb the gaps. Without gaps this is
    ``pca(X)`` exactly. The imputation starts from the span of the gap-free rows (at most
    ``start_components``), which it keeps when they explain the others exactly (noiseless data).
    With gaps, the subspace is learnt from at most ``max_rows`` evenly spaced rows (every SVD of the
    imputation is of that size: a 36,000-frame take took 26 s whole, ~1 s this way).
    Returns ``pca``'s four outputs for the filled rows.
    """
    X = np.asarray(X, dtype=np.float64)
    gaps = np.isnan(X)
    if gaps.any():
        X = X[~gaps.all(axis=1)]
        if len(X) > max_rows:
            X = X[np.linspace(0, len(X) - 1, max_rows).round().astype(np.int64)]
        gaps = np.isnan(X)
        if len(X) == 0:
            raise FacecapError("no frame with a visible coordinate to learn a subspace from")
        mean = np.nanmean(X, axis=0) if center else np.zeros(X.shape[1])
        Xf = X - mean
        full = ~gaps.any(axis=1)
        if full.any():  # start from the gap-free rows' span: exact when they span the rest, else only faster
            Xf = fill_gaps(Xf, np.zeros(X.shape[1]), pca(Xf[full], center=False, n_components=start_components)[1])[0]
        Xf[np.isnan(Xf)] = 0.0
        threshold = noise_threshold(np.linalg.svd(Xf, compute_uv=False), Xf.shape)
        scale = max(float(np.sqrt(np.mean(Xf**2))), 1e-300)
        for _ in range(max_iterations):
            U, s, Vt = np.linalg.svd(Xf, full_matrices=False)
            fit = (U * np.maximum(s - threshold, 0.0)) @ Vt
            step = float(np.sqrt(np.mean((fit[gaps] - Xf[gaps]) ** 2)))
            Xf[gaps] = fit[gaps]
            if step < tol * scale:
                break
        X = Xf + mean
    return pca(X, center=center, n_components=n_components, variance=variance)


def noise_threshold(s, shape):
    """Gavish & Donoho's optimal hard threshold for the singular values ``s`` of an ``shape`` (N, P)
    matrix whose noise level is unknown: ``omega(beta) * median(s)``, beta the aspect ratio."""
    beta = min(shape) / max(shape)
    return (0.56 * beta**3 - 0.95 * beta**2 + 1.82 * beta + 1.43) * float(np.median(s))


def gap_subspace(*frames, variance=0.99999, max_components=60):
    """(mean, components) for ``fill_gaps`` from the rows of several (F, P) arrays (the fitted
    examples/training frames and the take being solved), uncentred; rows with gaps count too
    (``pca_gappy``), as the gap-free ones alone may be little more than the neutral."""
    rows = [np.asarray(X, dtype=np.float64) for X in frames if X is not None]
    rows = np.concatenate(rows)
    rows = rows[np.isfinite(rows).any(axis=1)]
    if len(rows) == 0:
        raise FacecapError("no frame with a visible marker to learn the gap-filling subspace from")
    _, comps, _, _ = pca_gappy(rows, center=False, n_components=max_components, variance=variance)
    return np.zeros(rows.shape[1]), comps
