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

from ..errors import needs

with needs("scipy", "The temporal solve (smoothing over time)"):  # Blender has scipy only from the zip
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
        rows = (inv[frames[sel]].astype(itype) * K)[:, None] + idx  # rows of the frames' H, flattened
        m = sel.size * s * s
        H_ff = np.empty(m + s * s)  # the free blocks, one after the other, and a zero block as padding
        H_ff[m:] = 0.0
        # mode="clip": the indices are valid by construction, and "raise" buffers the output (2x slower)
        np.take(Hflat, ((rows * K)[:, :, None] + idx[:, None, :]).ravel(), out=H_ff[:m], mode="clip")
        # band rows of a frame: [j, d] = H_FF[j + d, j], a strided view (j + d >= s reads the next block
        # or the padding; masked out)
        skew = np.lib.stride_tricks.as_strided(H_ff, shape=(sel.size, s, s), strides=(8 * s * s, 8 * (s + 1), 8 * s),
                                               writeable=False)
        B[(base[sel][:, None] + np.arange(s)).ravel(), :s] = (skew * _band_mask(s)).reshape(-1, s)
    B[:, 0] += np.repeat(dT[frames], cnt)
    return B, base


_MASK = {}


def _band_mask(s):
    """(s, s) float mask of the band entries [j, d] with j + d < s."""
    out = _MASK.get(s)
    if out is None:
        j, d = np.indices((s, s))
        out = _MASK[s] = (j + d < s).astype(np.float64)
    return out


def _segment_couplings(ctx, a, b, edges):
    """The temporal couplings among the free variables of frames [a, b), grouped by segment.

    Variables are numbered from the window's first; ``edges`` are the segment edges (frames).
    Returns ((p, q, value), band, cross, reach): the entries, p < q; ``band[i]:band[i + 1]`` =
    segment i's entries with both ends inside it (sorted by p), ``cross[i]:cross[i + 1]`` = those
    reaching into the next segment (from its last two frames into the next one's first two), and
    ``reach[i]`` = the largest q - p inside segment i (0 if none)."""
    _, _, (_, o1, o2), lay, _ = ctx
    fr = lay.free[a:b]
    pos = lay.pos[a:b] - lay.offs[a]
    ps, qs, vs = [], [], []
    for lag, off in ((1, o1), (2, o2)):
        if b - a > lag and off.size:
            f, k = np.nonzero(fr[:-lag] & fr[lag:] & (off[a : b - lag] != 0)[:, None])
            ps.append(pos[f, k])
            qs.append(pos[f + lag, k])
            vs.append(off[a + f])
    if not ps:
        z = np.zeros(0, np.int64)
        n_seg = edges.size - 1
        empty = [0] * (n_seg + 1)
        return (z, z, np.zeros(0)), empty, empty, np.zeros(n_seg, np.int64)
    p, q, v = np.concatenate(ps), np.concatenate(qs), np.concatenate(vs)
    var = lay.offs[edges] - lay.offs[a]  # first variable of each segment, and the end
    inside = q < var[np.searchsorted(var, p, side="right")]
    # inside entries first, each group sorted by p: segment ranges by searchsorted
    order = np.lexsort((p, ~inside))
    p, q, v = p[order], q[order], v[order]
    n_in = int(inside.sum())
    band = np.searchsorted(p[:n_in], var[:-1]).tolist() + [n_in]
    cross = (n_in + np.searchsorted(p[n_in:], var[:-1])).tolist() + [p.size]
    d = q[:n_in] - p[:n_in]
    reach = np.zeros(edges.size - 1, np.int64)
    for i in range(edges.size - 1):
        if band[i + 1] > band[i]:
            reach[i] = d[band[i] : band[i + 1]].max()
    return (p, q, v), band, cross, reach


_TRIL = {}


def _tril(m):
    """Row and column indices of the lower triangle of an m x m matrix (cached)."""
    out = _TRIL.get(m)
    if out is None:
        out = _TRIL[m] = np.tril_indices(m)
    return out


def solve_window(ctx, rhs_free, a, b, seg=64, group=48, band=None):
    """Solve the free system of frames [a, b) (variables outside held at 0); returns x (n,).

    ``band``: optional (B, row) from ``frame_band`` for a set of frames including [a, b), with
    ``row[f]`` the first row of frame f; without it the bands are built ``group`` segments at a time.
    """
    lay = ctx[3]
    edges = _cuts(a, b, seg)
    var = lay.offs[edges] - lay.offs[a]
    (p, q, v), band_rng, cross_rng, reach = _segment_couplings(ctx, a, b, edges)
    cnt_max = np.maximum.reduceat(lay.cnt[a:b], edges[:-1] - a) if b > a else np.zeros(0, np.int64)
    rhs = rhs_free[lay.offs[a] : lay.offs[b]]
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
        v0, v1 = int(var[i]), int(var[i + 1])
        n = v1 - v0
        if n == 0:
            parts.append((0, None, None, None, 0))
            S = None
            continue
        mh_prev = 0 if S is None else S.shape[0]
        kd = max(int(cnt_max[i]) - 1, int(reach[i]), mh_prev - 1, 0)
        ab = np.zeros((kd + 1, n), order="F")
        w = min(B.shape[1], kd + 1)
        r0 = int(row[s0])
        ab[:w] = B[r0 : r0 + n, :w].T
        e0, e1 = band_rng[i], band_rng[i + 1]
        if e1 > e0:
            ab[q[e0:e1] - p[e0:e1], p[e0:e1] - v0] += v[e0:e1]
        r = rhs[v0:v1].copy()
        if S is not None:
            ii, jj = _tril(mh_prev)
            ab[ii - jj, jj] -= S[ii, jj]
            n_p, _, Z_p, y_p, m_p = parts[-1]
            r[:mh_prev] -= Z_p.T @ y_p[n_p - m_p :]
        cb, info = lapack.dpbtrf(ab, lower=1, overwrite_ab=1)
        if info:
            raise np.linalg.LinAlgError(f"temporal system not positive definite (dpbtrf info {info})")
        y, _ = lapack.dtbtrs(cb, r[:, None], uplo="L", trans="N")
        Z, m, S = None, 0, None
        c0, c1 = cross_rng[i], cross_rng[i + 1]
        if c1 > c0:
            # Q[tail of this segment, head of the next]: Z = L_tail^-1 C, the trailing m x m block of
            # the band factor being itself a band matrix (its last m columns)
            t0 = int(p[c0:c1].min())
            m = n - (t0 - v0)
            mh = int(q[c0:c1].max()) - v1 + 1
            C = np.zeros((m, mh))
            C[p[c0:c1] - t0, q[c0:c1] - v1] = v[c0:c1]
            Z, _ = lapack.dtbtrs(cb[:, n - m :], C, uplo="L", trans="N")
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
            y[n - m :] -= Z @ x_next[: Z.shape[1]]
        x, _ = lapack.dtbtrs(cb, y[:, None], uplo="L", trans="T")
        x_next = x[:, 0]
        out.append(x_next)
    return np.concatenate(out[::-1]) if out else np.zeros(0)


def context(Hp, inv, T, free):
    """Bundle what ``solve_window`` needs for one free set."""
    return (Hp.reshape(-1), inv, T, Layout(free), None)
