"""Banded Cholesky of the temporal kernel's free system, segment by segment along a frame window.

The free variables of frames ``a..b-1`` (frame-major, shapes in index order) form a banded SPD
system ``Q_FF x = r``: frame f couples with itself through ``H_f`` and with frames f +- 1, f +- 2
through the temporal operator. Its bandwidth follows the free counts of neighbouring frames, so one
LAPACK band for the whole take would be as wide as its worst pair of frames. Instead the window is
cut into segments of ``seg`` frames, each factorised with its own bandwidth (``dpbtrf``): a segment
only couples with the next one through its last two frames, so block Cholesky over the segments
passes a small dense Schur complement ``Z'Z`` (``Z = L_tail^-1 C``) from one segment to the next::

    L_s L_s' = Q_ss - E_head Z_(s-1)' Z_(s-1) E_head'
    forward  L_s y_s = r_s - E_head Z_(s-1)' y_(s-1),tail
    backward L_s' x_s = y_s - E_tail Z_s x_(s+1),head

The result is the exact solution of the window's system with the variables outside it held at 0
(the caller folds their values into ``r``). Each segment's band stays in cache and the work per
frame is about ``n_f (n_f + n_(f+1))^2`` instead of ``n_f (worst bandwidth)^2``. Inputs are trusted.
"""

import numpy as np
from scipy.linalg import lapack


class Layout:
    """Frame-major numbering of the free variables: ``pos[f, k]`` (valid where ``free[f, k]``)."""

    def __init__(self, free):
        self.free = free
        self.cnt = free.sum(axis=1)
        self.offs = np.concatenate([[0], np.cumsum(self.cnt)])
        self.pos = self.offs[:-1, None] + np.cumsum(free, axis=1) - 1


def _cuts(a, b, seg):
    """Segment edges of the frame window [a, b): about ``seg`` frames each, at least 3 if possible."""
    k = max(1, int(round((b - a) / seg)))
    return np.linspace(a, b, k + 1).round().astype(np.int64)


def frame_band(ctx, frames):
    """Within-frame blocks of the given frames (sorted indices) in row-wise band form:
    ``B[p, d] = Q[p + d, p]`` for free variables p, p + d of the same frame, rows in the order of
    ``frames`` (frame ``frames[i]`` starts at row ``start[i]``); the diagonal includes the temporal
    operator's. Gathered by free-set size, no per-frame loop. Returns (B, start)."""
    Hflat, inv, (dT, _, _), lay, _ = ctx
    K = lay.free.shape[1]
    fr = lay.free[frames]
    cnt = lay.cnt[frames]
    base = np.concatenate([[0], np.cumsum(cnt)])
    n = int(base[-1])
    base = base[:-1]
    B = np.zeros((n, max(int(cnt.max(initial=0)), 1)))
    order = np.argsort(~fr, axis=1, kind="stable").astype(np.int32)  # free shapes first, in order
    itype = np.int32 if Hflat.size < 2**31 else np.int64
    for s in np.unique(cnt):
        if s == 0:
            continue
        sel = np.flatnonzero(cnt == s)
        idx = order[sel, :s].astype(itype)
        jd, j, keep = _band_index(s)
        # B rows of a frame: B[j, d] = H[idx[j + d], idx[j]] for j + d < s, else 0
        rows = (inv[frames[sel]].astype(itype) * K)[:, None] + idx
        vals = np.take(Hflat, (rows[:, jd] * K) + idx[:, j])
        vals *= keep
        B[(base[sel][:, None] + np.arange(s)).ravel(), :s] = vals.reshape(-1, s)
    B[:, 0] += np.repeat(dT[frames], cnt)
    return B, base


_INDEX = {}


def _band_index(s):
    """(jd, j, keep) of shape (s, s): row index min(j + d, s - 1), column j, and j + d < s."""
    out = _INDEX.get(s)
    if out is None:
        j, d = np.indices((s, s))
        out = _INDEX[s] = (np.minimum(j + d, s - 1), j, (j + d < s).astype(np.float64))
    return out


def _band(ctx, B, r0, s0, s1, kd_min):
    """Lower band storage (kd + 1, n) of Q restricted to the free variables of frames [s0, s1);
    their within-frame band is ``B[r0 : r0 + n]`` (see ``frame_band``)."""
    _, _, (_, o1, o2), lay, _ = ctx
    fr = lay.free[s0:s1]
    pl = lay.pos[s0:s1] - lay.offs[s0]
    n = int(lay.offs[s1] - lay.offs[s0])
    kd = max(int(lay.cnt[s0:s1].max()) - 1, kd_min)
    couple = []
    for lag, off in ((1, o1), (2, o2)):
        if s1 - s0 > lag and off.size:
            f, k = np.nonzero(fr[:-lag] & fr[lag:])
            p, q = pl[f, k], pl[f + lag, k]
            couple.append((q - p, p, off[s0 + f]))
            kd = max(kd, int((q - p).max(initial=0)))
    ab = np.zeros((kd + 1, n), order="F")
    w = min(B.shape[1], kd + 1)
    ab[:w] = B[r0 : r0 + n, :w].T
    for dd, p, v in couple:
        ab[dd, p] += v
    return ab, kd


def _tail_coupling(ctx, s0, s1, s2):
    """Dense Q[tail of [s0, s1), head of [s1, s2)]: tail = last two frames, head = first two."""
    _, _, (_, o1, o2), lay, _ = ctx
    free, pos, offs = lay.free, lay.pos, lay.offs
    t0 = max(s0, s1 - 2)
    h1 = min(s2, s1 + 2)
    m = int(offs[s1] - offs[t0])
    mh = int(offs[h1] - offs[s1])
    C = np.zeros((m, mh))
    for f, g, off in ((s1 - 2, s1, o2), (s1 - 1, s1, o1), (s1 - 1, s1 + 1, o2)):
        if f < t0 or g >= h1 or f >= off.size or not off[f]:
            continue
        both = free[f] & free[g]
        C[pos[f, both] - offs[t0], pos[g, both] - offs[s1]] += off[f]
    return C, m, mh


def solve_window(ctx, rhs_free, a, b, seg=64, group=48, band=None):
    """Solve the free system of frames [a, b) (variables outside held at 0); returns x (n,).

    ``band``: optional (B, row) from ``frame_band`` for a set of frames including [a, b), with
    ``row[f]`` the first row of frame f; without it the bands are built ``group`` segments at a time.
    """
    lay = ctx[3]
    edges = _cuts(a, b, seg)
    parts = []
    S = None
    B, row = band if band is not None else (None, None)
    b1 = a if band is None else b
    for i in range(edges.size - 1):
        s0, s1 = int(edges[i]), int(edges[i + 1])
        if s1 > b1:  # within-frame bands for the next group of segments (bounded memory)
            b1 = int(edges[min(i + group, edges.size - 1)])
            B, start = frame_band(ctx, np.arange(s0, b1))
            row = np.empty(lay.free.shape[0], dtype=np.int64)
            row[s0:b1] = start
        n = int(lay.offs[s1] - lay.offs[s0])
        r = rhs_free[lay.offs[s0] : lay.offs[s1]].copy()
        if n == 0:
            parts.append((n, None, None, None, 0))
            S = None
            continue
        mh_prev = 0 if S is None else S.shape[0]
        ab, kd = _band(ctx, B, int(row[s0]), s0, s1, max(mh_prev - 1, 0))
        if S is not None:
            ii, jj = np.tril_indices(mh_prev)
            ab[ii - jj, jj] -= S[ii, jj]
            r[:mh_prev] -= parts[-1][2].T @ parts[-1][3][-parts[-1][4]:]
        cb, info = lapack.dpbtrf(ab, lower=1, overwrite_ab=1)
        if info:
            raise np.linalg.LinAlgError(f"temporal system not positive definite (dpbtrf info {info})")
        y, _ = lapack.dtbtrs(cb, r[:, None], uplo="L", trans="N")
        Z, m = None, 0
        S = None
        if i + 2 < edges.size:
            C, m, mh = _tail_coupling(ctx, s0, s1, int(edges[i + 2]))
            if m and mh and C.any():
                ii, jj = np.tril_indices(m)
                ok = ii - jj <= kd
                Lt = np.zeros((m, m))
                Lt[ii[ok], jj[ok]] = cb[(ii - jj)[ok], n - m + jj[ok]]
                Z, _ = lapack.dtrtrs(Lt, C, lower=1)
                S = Z.T @ Z
        parts.append((n, cb, Z, y[:, 0], m))
    out = []
    x_next = None
    for n, cb, Z, y, m in reversed(parts):
        if n == 0:
            out.append(np.zeros(0))
            x_next = None
            continue
        if Z is not None and x_next is not None:
            y = y.copy()
            y[-m:] -= Z @ x_next[: Z.shape[1]]
        x, _ = lapack.dtbtrs(cb, y[:, None], uplo="L", trans="T")
        x_next = x[:, 0]
        out.append(x_next)
    return np.concatenate(out[::-1]) if out else np.zeros(0)


def context(Hp, inv, T, free):
    """Bundle what ``solve_window`` needs for one free set."""
    return (Hp.reshape(-1), inv, T, Layout(free), None)
