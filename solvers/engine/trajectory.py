"""Active-set predictor of the whole-take kernel: each shape's trajectory solved on its own.

Why: near a run of frames held at a bound, second differences act like a beam resting on a
support. When the run is too long, only its first frame feels the pull to leave it (the next ones
are pushed back by the curve bending over them), so plain active-set steps shorten the run by one
frame per iteration, and every iteration is a full banded solve of the take. Measured on the
36,000-frame sample take: the count of wrong variables fell only about 3x per iteration, and runs
needed up to 10 iterations to settle.

What: after an exact solve and its classification, take every variable whose state changes, a
window of ``pad`` frames around it in its own shape, and solve that shape's box/L1 problem over
the window with everything else held where it is: one pentadiagonal system per shape window, all
stacked in one band of width 2, iterated to its own active set. That costs O(frames in windows)
per round instead of a K-wide band, so runs move by as many frames as they need in one outer
iteration. The result is only a prediction of the states; the exact iteration that follows
checks it (KKT) and corrects what the coupling between shapes changes, so the optimum is unchanged.
"""

import numpy as np

from ..errors import needs
from .states import FREE, ZERO, classify, fixed_values

with needs("scipy", "The temporal solve (smoothing over time)"):  # Blender has scipy only from the zip
    from scipy.linalg import lapack

#: Frames of a shape's trajectory around each change that the predictor re-solves.
PAD = 8
#: Rounds of the predictor's own active-set iteration (measured: 13 at most on the sample take).
ROUNDS = 40


def dilate(mask, pad):
    """``mask`` (frames first) grown by ``pad`` frames both ways."""
    out = mask.copy()
    for s in range(1, pad + 1):
        out[s:] |= mask[:-s]
        out[:-s] |= mask[s:]
    return out


def pentadiagonal_mul(diag, c1, c2, x):
    """y = M x for the symmetric M with diagonal ``diag`` and off-diagonals ``c1`` (lag 1), ``c2``
    (lag 2), along the first axis of x (coefficients broadcast, e.g. (F, 1) against (F, K))."""
    y = diag * x
    y[:-1] += c1 * x[1:]
    y[1:] += c1 * x[:-1]
    y[:-2] += c2 * x[2:]
    y[2:] += c2 * x[:-2]
    return y


def _sub_couplings(pos, c1, c2):
    """Couplings (c1, c2) among the entries ``pos`` (sorted) of a system with couplings c1, c2:
    entries 1 apart couple through c1, entries 2 apart (one left out between) through c2."""
    if pos.size == c1.size + 1:
        return c1, c2
    if pos.size < 2:
        return c1[:0], c2[:0]
    g = pos[1:] - pos[:-1]
    s1 = np.where(g == 1, c1[np.minimum(pos[:-1], c1.size - 1)], 0.0)
    if c2.size:
        s1 = np.where(g == 2, c2[np.minimum(pos[:-1], c2.size - 1)], s1)
        s2 = np.where(pos[2:] - pos[:-2] == 2, c2[np.minimum(pos[:-2], c2.size - 1)], 0.0)
    else:
        s2 = np.zeros(max(pos.size - 2, 0))
    return s1, s2


def _round(diag, couplings, w0, g0, lo0, hi0, lam0, st, sg):
    """One active-set round of the stacked trajectory windows: solve the free entries with the
    fixed ones at their values, classify. Returns (state, sign), or None if not positive definite."""
    c1, c2 = couplings
    free = st == FREE
    d = np.where(free, 0.0, fixed_values(st, lo0, hi0) - w0)
    rhs = g0 + pentadiagonal_mul(diag, c1, c2, d) + lam0 * np.where(free, sg, 0.0)
    fi = np.flatnonzero(free)
    if fi.size:
        # the free entries' system, compressed: still pentadiagonal (couplings reach 2 frames)
        ab = np.zeros((3, fi.size), order="F")
        ab[0] = diag[fi]
        sub1, sub2 = _sub_couplings(fi, c1, c2)
        ab[1, :-1] = sub1
        ab[2, :-2] = sub2
        _, x, info = lapack.dpbsv(ab, -rhs[fi], lower=1)
        if info:
            return None
        d[fi] = x
    step = 1.0 / diag
    v = (w0 + d) - step * (g0 + pentadiagonal_mul(diag, c1, c2, d))
    st_new, sg_new = classify(v[None], step[None], lo0[None], hi0[None], lam0[None])
    st_new, sg_new = st_new[0], sg_new[0]
    flip = (st == FREE) & (st_new == FREE) & (sg_new != sg) & (lam0 > 0)  # as the kernel: stop at 0 first
    st_new[flip] = ZERO
    return st_new, sg_new


def predict_states(w, grad, state, sign, changed, curvature, lo, hi, lam, T, frames, pad=PAD, rounds=ROUNDS):
    """Predicted (state, sign) for the rows ``frames`` (sorted frame numbers) of the take.

    ``w``, ``grad`` (= Q w - G), ``state``, ``sign`` (the classification just made), ``changed``,
    ``curvature`` (Q's diagonal), ``lo``, ``hi``: (n_rows, K) for those frames; ``lam`` (K,); ``T``
    the temporal operator's diagonals. Returns new arrays, or the inputs if the windows' system is
    not positive definite (it is a principal submatrix of Q, so only rounding can do that).
    """
    n_rows, K = w.shape
    mask = dilate(changed, pad)
    ks, rs = np.nonzero(mask.T)  # shape-major: a shape's window frames are consecutive
    if ks.size == 0:
        return state, sign
    fs = frames[rs]
    same = ks[1:] == ks[:-1]
    gap1 = np.where(same, fs[1:] - fs[:-1], 0)
    _, off1, off2 = T
    # coupling of each entry with the next (frames 1 or 2 apart: the frame between is outside the window)
    c1 = np.where(gap1 == 1, off1[np.minimum(fs[:-1], off1.size - 1)] if off1.size else 0.0, 0.0)
    if off2.size:
        c1 = np.where(gap1 == 2, off2[np.minimum(fs[:-1], off2.size - 1)], c1)
        gap2 = np.where(same[1:] & same[:-1], fs[2:] - fs[:-2], 0)
        c2 = np.where(gap2 == 2, off2[np.minimum(fs[:-2], off2.size - 1)], 0.0)
    else:
        c2 = np.zeros(max(ks.size - 2, 0))
    diag = curvature[rs, ks]
    w0, g0 = w[rs, ks], grad[rs, ks]
    lo0, hi0, lam0 = lo[rs, ks], hi[rs, ks], lam[ks]
    st, sg = state[rs, ks].copy(), sign[rs, ks].copy()
    # windows that do not couple (another shape, or 3+ frames apart) are independent problems:
    # each round only re-solves the windows whose states changed in the last one
    comp = np.concatenate([[0], np.cumsum(c1 == 0)])
    pos = np.arange(ks.size)  # the entries still iterating
    for _ in range(rounds):
        new = _round(diag[pos], _sub_couplings(pos, c1, c2), w0[pos], g0[pos], lo0[pos], hi0[pos], lam0[pos],
                     st[pos], sg[pos])
        if new is None:
            return state, sign
        st_new, sg_new = new
        moved = st_new != st[pos]
        st[pos], sg[pos] = st_new, sg_new
        if not moved.any():
            break
        live = np.zeros(comp[-1] + 1, dtype=bool)
        live[comp[pos[moved]]] = True
        pos = pos[live[comp[pos]]]
    state, sign = state.copy(), sign.copy()
    state[rs, ks], sign[rs, ks] = st, sg
    return state, sign
