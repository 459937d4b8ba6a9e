"""Whole-take kernel of the engine: one box/L1 QP over all frames, coupled by smoothing.

Over the stacked weights w (F*K, frame-major)::

    minimise  1/2 w' Q w - g' w + sum lam |w|   subject to  lo <= w <= hi
    Q = blockdiag(H_f) + (mu1 D1'D1 + mu2 D2'D2) (x) I_K

Q is block-pentadiagonal: each frame couples with itself through H_f (dense K x K) and with
frames f +- 1, f +- 2 through diagonal blocks. The same primal-dual active-set iteration as the
per-frame kernel runs on the whole take (started from the per-frame solution); in each iteration
the free variables solve Q_FF x = r, a banded SPD system in frame-major order whose bandwidth is
about twice the number of free shapes per frame, by LAPACK's banded Cholesky (``solveh_banded``).
It is exact: the result is the optimum once the active set has settled.
"""

import numpy as np
from scipy.linalg import solveh_banded

from .engine_frames import _FREE, classify, fixed_values, hmul, pattern_hessians, patterns, solve_frames


def temporal_operator(F, mu1, mu2):
    """Diagonal and first/second off-diagonals of mu1 D1'D1 + mu2 D2'D2 (F x F, symmetric)."""
    diag = np.zeros(F)
    off1 = np.zeros(max(F - 1, 0))
    off2 = np.zeros(max(F - 2, 0))
    if F >= 2 and mu1:
        diag[:-1] += mu1
        diag[1:] += mu1
        off1 -= mu1
    if F >= 3 and mu2:
        for a, ca in enumerate((1.0, -2.0, 1.0)):
            diag[a : F - 2 + a] += mu2 * ca * ca
        off1[: F - 2] += mu2 * (1.0 * -2.0)  # (0,1) pairs
        off1[1 : F - 1] += mu2 * (-2.0 * 1.0)  # (1,2) pairs
        off2 += mu2 * 1.0
    return diag, off1, off2


def _tmul(T, X):
    diag, off1, off2 = T
    Y = diag[:, None] * X
    if off1.size:
        Y[:-1] += off1[:, None] * X[1:]
        Y[1:] += off1[:, None] * X[:-1]
    if off2.size:
        Y[:-2] += off2[:, None] * X[2:]
        Y[2:] += off2[:, None] * X[:-2]
    return Y


def _banded_solve(Hp, inv, T, free, rhs):
    """Solve Q_FF x_F = rhs_F (frame-major order of the free variables)."""
    F, K = free.shape
    cnt = free.sum(axis=1)
    offs = np.concatenate([[0], np.cumsum(cnt)])
    n = int(offs[-1])
    x = np.zeros((F, K))
    if n == 0:
        return x
    pos = np.where(free, offs[:-1, None] + np.cumsum(free, axis=1) - 1, -1)
    diag, off1, off2 = T
    # bandwidth
    b = int(cnt.max()) - 1
    d1 = d2 = None
    if off1.size:
        m1 = free[:-1] & free[1:]
        d1 = (pos[1:] - pos[:-1])[m1]
        b = max(b, int(d1.max(initial=0)))
    if off2.size:
        m2 = free[:-2] & free[2:]
        d2 = (pos[2:] - pos[:-2])[m2]
        b = max(b, int(d2.max(initial=0)))
    ab = np.zeros((b + 1, n))
    # within-frame blocks, gathered by free-set size
    idx_all = np.argsort(~free, axis=1, kind="stable")
    flat_H = Hp.reshape(-1)
    for s in np.unique(cnt):
        if s == 0:
            continue
        sel = np.flatnonzero(cnt == s)
        idx = idx_all[sel, :s]
        M = flat_H[(inv[sel] * (K * K))[:, None, None] + (idx * K)[:, :, None] + idx[:, None, :]]
        base = offs[sel][:, None]
        for d in range(s):
            ab[d, (base + np.arange(s - d)).ravel()] = np.diagonal(M, offset=-d, axis1=1, axis2=2).ravel()
    # temporal couplings
    ab[0, pos[free]] += np.broadcast_to(diag[:, None], (F, K))[free]
    if d1 is not None and d1.size:
        ab[d1, pos[:-1][m1]] += np.broadcast_to(off1[:, None], (F - 1, K))[m1]
    if d2 is not None and d2.size:
        ab[d2, pos[:-2][m2]] += np.broadcast_to(off2[:, None], (F - 2, K))[m2]
    sol = solveh_banded(ab, rhs[free], lower=True, check_finite=False)
    x[free] = sol
    return x


def solve_temporal(A, C, G, R, lo, hi, lam, mu, *, max_iter=40, chunk=4096):
    """Solve the whole take. Shapes as in ``engine_frames.solve_frames``; mu = (mu1, mu2) absolute.

    Returns (W (F, K), iterations, converged).
    """
    F, K = G.shape
    pats, inv = patterns(C)
    Hp = pattern_hessians(A, pats, R)
    T = temporal_operator(F, *mu)

    # start from the per-frame optimum (frames without data: their rest value)
    w = np.clip(0.0, lo, hi).astype(float)
    has = C.sum(axis=1) > 0
    if has.any():
        idx = np.flatnonzero(has)
        w[idx] = solve_frames(A, C[idx], G[idx], R, lo[idx], hi[idx], lam, max_iter=max_iter, chunk=chunk)[0]

    def qmul(X):
        return hmul(Hp, inv, X) + _tmul(T, X)

    step = 1.0 / np.maximum(np.einsum("nkk->n", Hp)[inv] / K + T[0], 1e-300)
    grad = qmul(w) - G
    prev = prev_sg = None
    for it in range(1, max_iter + 1):
        st, sg = classify(w - step[:, None] * grad, step, lo, hi, lam)
        if prev is not None:
            changed = (st != prev) | ((st == _FREE) & (sg != prev_sg) & (lam > 0))
            if not changed.any():
                return w, it, True
        free = st == _FREE
        xf = fixed_values(st, lo, hi)
        rhs = G - qmul(xf)
        if np.any(lam > 0):
            rhs -= lam * np.where(free, sg, 0.0)
        w = xf + _banded_solve(Hp, inv, T, free, rhs)
        grad = qmul(w) - G
        prev, prev_sg = st, sg
    return np.clip(w, lo, hi), max_iter, False  # active-set iterates can leave the box
