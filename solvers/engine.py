"""The weight solve shared by every strategy: bounded, regularised, masked least squares.

For each frame f::

    minimise  || m_f * (A w_f - d_f) ||^2 + lam * ||w_f||^2   subject to  lower <= w_f <= upper

where ``m_f`` are per-coordinate weights (0 for gaps). Frames are solved together: the
normal matrices are built once per distinct mask pattern and a primal-dual active-set
iteration (Hintermueller, Ito & Kunisch 2002) runs on all frames at once with batched
linear solves. Frames where it does not settle fall back to scipy's exact BVLS.
"""

from dataclasses import dataclass, field

import numpy as np

from .errors import FacecapError


@dataclass(frozen=True, eq=False)
class SolveResult:
    """Weights and diagnostics of a solve.

    weights : (F, K), NaN for frames with no data
    residuals : (F, P), mask * (A w - d), 0 where masked
    at_bound : (F,) number of weights at a bound
    solved : (F,) bool, False where a frame had no data
    iterations : int, active-set iterations used
    fallback_frames : int, frames handed to the exact BVLS fallback
    """

    weights: np.ndarray
    residuals: np.ndarray
    at_bound: np.ndarray
    solved: np.ndarray
    iterations: int = 0
    fallback_frames: int = 0
    warnings: tuple = field(default_factory=tuple)


def solve_bounded(A, D, *, mask=None, lower=0.0, upper=1.0, regularisation=0.0, max_iter=40, chunk=4096):
    """Solve the bounded, regularised least-squares problem for every frame.

    Parameters
    ----------
    A : ndarray, shape (P, K)
        Basis matrix: column k is shape k's effect on the P observed coordinates.
    D : ndarray, shape (F, P)
        Observed coordinates (deltas from neutral); NaN entries are treated as missing.
    mask : ndarray, shape (F, P), optional
        Non-negative weight per coordinate (confidence); 0 drops it. Default: 1 where D is finite.
    lower, upper : float or ndarray (K,)
        Bounds on the weights.
    regularisation : float
        Ridge weight ``lam`` (absolute, in the units of ``A^T A``).
    max_iter : int
        Active-set iterations before the exact fallback takes over.
    chunk : int
        Frames solved per batch (bounds memory to chunk * K * K floats).

    Returns
    -------
    SolveResult
    """
    A = np.asarray(A, dtype=np.float64)
    D = np.asarray(D, dtype=np.float64)
    if A.ndim != 2:
        raise FacecapError(f"`A` must have shape (P, K); got {A.shape}")
    P, K = A.shape
    if D.ndim != 2 or D.shape[1] != P:
        raise FacecapError(f"`D` must have shape (F, {P}); got {D.shape}")
    if not np.isfinite(A).all():
        raise FacecapError("`A` must be finite")
    finite = np.isfinite(D)
    m = finite.astype(np.float64) if mask is None else np.where(finite, np.asarray(mask, dtype=np.float64), 0.0)
    if m.shape != D.shape or np.any(m < 0):
        raise FacecapError(f"`mask` must be non-negative with shape {D.shape}")
    lo = np.broadcast_to(np.asarray(lower, dtype=np.float64), (K,)).copy()
    hi = np.broadcast_to(np.asarray(upper, dtype=np.float64), (K,)).copy()
    if np.any(lo > hi):
        raise FacecapError("`lower` must not exceed `upper`")
    if regularisation < 0:
        raise FacecapError(f"`regularisation` must be >= 0; got {regularisation}")

    # A tiny ridge floor keeps unobservable shapes (zero columns) at their smallest-norm value.
    scale = float(np.mean(np.einsum("pk,pk->k", A, A))) or 1.0
    lam = regularisation + 1e-12 * scale

    Dz = np.where(m > 0, D, 0.0)
    G = (m * Dz) @ A  # (F, K) = A^T diag(m_f) d_f, since m is 0/1 or a weight applied once
    patterns, inverse = np.unique(m, axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    Hp = np.einsum("pk,np,pl->nkl", A, patterns, A, optimize=True) + lam * np.eye(K)

    F = D.shape[0]
    W = np.full((F, K), np.nan)
    solved = m.sum(axis=1) > 0
    iters = 0
    fallback = 0
    frames = np.flatnonzero(solved)
    for start in range(0, frames.size, chunk):
        idx = frames[start : start + chunk]
        H = Hp[inverse[idx]]
        w, it, unsettled = _pdas(H, G[idx], lo, hi, max_iter)
        if unsettled.size:
            w[unsettled] = _bvls_fallback(H[unsettled], G[idx][unsettled], lo, hi)
            fallback += unsettled.size
        W[idx] = w
        iters = max(iters, it)

    Wz = np.nan_to_num(W)
    residuals = m * (Wz @ A.T - Dz)
    tol = 1e-9 * np.maximum(1.0, np.abs(hi - lo))
    at_bound = ((np.abs(Wz - lo) <= tol) | (np.abs(Wz - hi) <= tol)).sum(axis=1)
    at_bound[~solved] = 0
    notes = ()
    if (~solved).any():
        notes = (f"{int((~solved).sum())} frame(s) had no visible markers and were not solved",)
    return SolveResult(W, residuals, at_bound, solved, iters, fallback, notes)


def _pdas(H, g, lo, hi, max_iter):
    """Primal-dual active-set iteration on min 1/2 w'Hw - g'w, lo <= w <= hi, batched over frames.

    Returns (w, iterations, indices of frames that did not settle).
    """
    n, K = g.shape
    w = np.clip(np.linalg.solve(H, g[:, :, None])[:, :, 0], lo, hi)
    c = 1.0 / np.maximum(np.einsum("nkk->nk", H).mean(axis=1), 1e-300)
    eye = np.eye(K, dtype=bool)
    prev_l = np.zeros((n, K), dtype=bool)
    prev_u = np.zeros((n, K), dtype=bool)
    active = np.arange(n)
    it = 0
    for it in range(1, max_iter + 1):
        Ha, ga, wa = H[active], g[active], w[active]
        mu = np.einsum("nkl,nl->nk", Ha, wa) - ga
        v = wa - c[active, None] * mu
        low = v < lo
        up = v > hi
        if it > 1:
            settled = ~((low != prev_l[active]) | (up != prev_u[active])).any(axis=1)
            keep = ~settled
            active, Ha, ga, low, up = active[keep], Ha[keep], ga[keep], low[keep], up[keep]
            if active.size == 0:
                return w, it, active
        free = ~(low | up)
        fixed = np.where(low, lo, np.where(up, hi, 0.0))
        M = np.where(free[:, :, None] & free[:, None, :], Ha, 0.0) + (eye & ~free[:, :, None])
        rhs = np.where(free, ga - np.einsum("nkl,nl->nk", Ha, fixed), fixed)
        w[active] = np.linalg.solve(M, rhs[:, :, None])[:, :, 0]
        prev_l[active] = low
        prev_u[active] = up
    return w, it, active


def _bvls_fallback(H, g, lo, hi):
    """Exact per-frame solve via scipy's BVLS on the Cholesky square root of H."""
    from scipy.optimize import lsq_linear

    out = np.empty_like(g)
    for i in range(g.shape[0]):
        L = np.linalg.cholesky(H[i])
        b = np.linalg.solve(L, g[i])
        res = lsq_linear(L.T, b, bounds=(lo, hi), method="bvls", tol=1e-14)
        out[i] = res.x
    return out
