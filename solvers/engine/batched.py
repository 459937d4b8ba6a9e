"""Batched linear algebra over frames whose matrices are per-pattern: products ``y_f = H_p(f) x_f``
and solves of each frame's free (or fixed) subsystem, grouped so that numpy makes one call per
pattern or per subsystem size rather than one per frame."""

import numpy as np


def hmul(Hp, inv, x):
    """y_f = H_{inv[f]} x_f for every row of x."""
    n_pat = Hp.shape[0]
    if n_pat == 1:
        return x @ Hp[0]
    if n_pat * 2 > x.shape[0]:  # few rows per pattern: one gathered einsum (GIL-free in threads)
        return np.einsum("nkl,nl->nk", Hp[inv], x)
    return hmul_by_pattern(Hp, inv, x)


def hmul_by_pattern(Hp, inv, x):
    """``hmul`` as one product per pattern present: rows sorted by pattern, slices, no gather of
    the matrices. Faster single-threaded for many rows (the temporal kernel); its Python loop makes
    it slower than the einsum in the threaded per-frame kernel (measured)."""
    n = x.shape[0]
    if n <= 256:  # few rows: gathering their matrices is cheap
        return np.einsum("nkl,nl->nk", Hp[inv], x)
    order = np.argsort(inv, kind="stable")
    si = inv[order]
    starts = np.flatnonzero(np.concatenate([[True], si[1:] != si[:-1]]))
    ends = np.append(starts[1:], n)
    xs = x[order]
    ys = np.empty_like(xs)
    for a, b, p in zip(starts.tolist(), ends.tolist(), si[starts].tolist()):
        ys[a:b] = xs[a:b] @ Hp[p]
    y = np.empty_like(x)
    y[order] = ys
    return y


def solve_free(Hp, inv, free, rhs):
    """x with x_F = H_FF^{-1} rhs_F per frame (0 elsewhere), batched by free-set size."""
    n, K = free.shape
    x = np.zeros((n, K))
    cnt = free.sum(axis=1)
    itype = np.int32 if Hp.size < 2**31 else np.int64  # smaller index arrays gather faster
    idx_all = np.argsort(~free, axis=1, kind="stable").astype(itype)  # free indices first, in order
    inv_k = inv.astype(itype) * K
    flat_H = Hp.reshape(-1)
    order = np.lexsort((inv, cnt))  # by size, then by pattern (cache-friendly gathers)
    sizes = cnt[order]
    starts = np.searchsorted(sizes, np.arange(K + 2))
    for s in range(1, K + 1):
        sel = order[starts[s] : starts[s + 1]]
        if sel.size == 0:
            continue
        idx = idx_all[sel, :s]
        rows = inv_k[sel][:, None] + idx  # row of H_p, flattened over patterns
        M = np.take(flat_H, (rows * K)[:, :, None] + idx[:, None, :])
        b = np.take_along_axis(rhs[sel], idx, axis=1)
        sol = np.linalg.solve(M, b[:, :, None])[:, :, 0]
        x[sel[:, None], idx] = sol
    return x
