"""Whole-take kernel of the engine: one box/L1 QP over all frames, coupled by smoothing.

Over the stacked weights w (F*K, frame-major)::

    minimise  1/2 w' Q w - g' w + sum lam |w|   subject to  lo <= w <= hi
    Q = blockdiag(H_f) + (mu1 D1'D1 + mu2 D2'D2) (x) I_K

Q is block-pentadiagonal: each frame couples with itself through H_f (dense K x K) and with
frames f +- 1, f +- 2 through diagonal blocks. The same primal-dual active-set iteration as the
per-frame kernel runs on the whole take, started from two per-frame active-set iterations (a guess
is enough). In each iteration the free variables solve Q_FF x = r, a banded SPD system in
frame-major order, by the segment-wise banded Cholesky of ``engine_banded``. Only the frames whose
residual is off are re-solved: the first passes touch the whole take, later ones (a few frames
changing state) solve windows of ``pad`` frames around the changes, then around the windows' edges
until the residual is at rounding level everywhere (the solution of a local change decays within
a few frames). The gradient is updated from each window's change and only frames near a change
are reclassified, so late iterations cost their windows, not the take. It is exact: the result
is the optimum once the active set has settled.

Runs of frames held at a bound that are too long shrink by only one frame per plain iteration
(second differences act like a beam on a support), so from the second classification on, the new
states go through a predictor that solves each changing shape's trajectory on its own
(``engine_trajectory``, cheap: one band of width 2); the exact iteration then checks and corrects
them. Measured on the 36,000-frame sample take: 15 iterations per half before, 9 now (8.2/7.6 s
against 5.5 s single-threaded on 18,000 frames).

Plain active-set steps are not globally convergent here (Q is not an M-matrix), so three rules keep
them from cycling: each variable's proximal step is its own curvature 1 / Q_kk (no jumps from one
bound straight to the other); a free weight whose sign changes under L1 stops at 0 first; and when
the count of wrong variables stops falling, only the first wrong variable of each group of frames
changes until it falls again (after Judice & Pires' block-pivoting safeguard). Measured on 1,500-
frame slices of the sample take with L1 1-10^4 times the default, smoothing 0.1-10 times and
kinks at 0: 15 of 24 configurations ran out of 40 iterations before, 1 runs out of 200 now.

Long takes (``SPLIT_FRAMES`` and more) are solved in windows of ``WINDOW_FRAMES`` frames whose seams
are then settled exactly (``engine.windows``): the same optimum, in the memory of one window per
process (the first pass's windows are shared by two processes, ``engine.split``). Measured on
100 minutes at 60 fps of the sample character: see docs/performance.md.
"""

import numpy as np

from .banded import context, frame_band, solve_window
from . import windows
from .batched import hmul_by_pattern
from .frames import pattern_hessians, patterns, reusable, solve_frames
from .split import run_beside
from .states import FREE, ZERO, classify, fixed_values
from .threads import single_blas_thread
from .trajectory import dilate, pentadiagonal_mul, predict_states


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
    """(mu1 D1'D1 + mu2 D2'D2) X over the frames (rows) of X."""
    diag, off1, off2 = T
    return pentadiagonal_mul(diag[:, None], off1[:, None], off2[:, None], X)


#: Per-frame active-set iterations for the starting guess (a guess: more iterations measured no
#: fewer temporal passes on the bench take).
INIT_ITER = 2


def _windows(bad, pad, F):
    """Frame intervals [a, b) covering every frame of ``bad`` dilated by ``pad`` (touching ones merged)."""
    idx = np.flatnonzero(bad)
    a = np.maximum(idx - pad, 0)
    b = np.minimum(idx + pad + 1, F)
    new = np.concatenate([[True], a[1:] > b[:-1] + 2])  # closer than 3 frames: still coupled, merge
    starts = a[new]
    ends = np.maximum.reduceat(b, np.flatnonzero(new))
    return list(zip(starts.tolist(), ends.tolist()))


#: Frames whose within-frame bands are built together when a pass solves many small windows.
BAND_FRAMES = 4096


def _batches(wins, limit):
    """Consecutive windows grouped so each group spans at most ``limit`` frames (or one window)."""
    out, cur, size = [], [], 0
    for a, b in wins:
        if cur and size + (b - a) > limit:
            out.append(cur)
            cur, size = [], 0
        cur.append((a, b))
        size += b - a
    if cur:
        out.append(cur)
    return out


def _qdelta(qmul_rows, T, delta, rows):
    """Q @ delta for delta non-zero only on the frames ``rows`` (bool (F,)): the within-frame part on
    those rows, the temporal part (cheap, diagonal blocks) on the whole take."""
    y = _tmul(T, delta)
    if rows.mean() > 0.5:
        return y + qmul_rows(delta, None)
    idx = np.flatnonzero(rows)
    y[idx] += qmul_rows(delta[idx], idx)
    return y


def _settle(ctx, qmul_rows, T, G, w, grad, free, lin, tol, pad, max_rounds=8):
    """Make w exact on the free set: solve ``Q_FF w_F = G_F - lin_F - Q_FB w_B`` by banded windows
    around the frames whose residual exceeds ``tol`` (all of them at first; afterwards only the
    edges of earlier windows and frames whose state changed); the last round, if reached, solves
    the whole take at once. ``grad`` (= Q w - G on entry) is updated from each round's change only,
    so rounds and iterations that touch a few windows cost only those windows.
    Returns (w, grad, touched): touched = frames whose w or grad changed."""
    F = w.shape[0]
    touched = np.zeros(F, dtype=bool)
    for rnd in range(max_rounds):
        res = grad + lin
        res[~free] = 0.0
        bad = (np.abs(res) > tol).any(axis=1)
        if not bad.any():
            break
        r_free = -res[free]
        delta = np.zeros_like(w)
        wins = _windows(bad, pad, F) if rnd < max_rounds - 1 else [(0, F)]
        moved = np.zeros(F, dtype=bool)
        for batch in _batches(wins, BAND_FRAMES):
            band = None
            if len(batch) > 1:  # many small windows: build their within-frame bands at once
                frames = np.concatenate([np.arange(a, b) for a, b in batch])
                B, start = frame_band(ctx, frames)
                row = np.empty(F, dtype=np.int64)
                row[frames] = start
                band = (B, row)
            for a, b in batch:
                delta[a:b][free[a:b]] = solve_window(ctx, r_free, a, b, band=band)
                moved[a:b] = True
        w = w + delta
        grad = grad + _qdelta(qmul_rows, T, delta, moved)
        touched |= dilate(moved, 2)  # where Q couples them
    return w, grad, touched


#: Takes at least this long are solved in windows (``engine.windows``): memory bounded by a window,
#: and the windows of the first pass shared by two processes (``engine.split``) where possible.
SPLIT_FRAMES = 6000
#: Frames each window of the first pass runs past its core on both sides, so that its free ends are
#: far from the seams (the seam windows then only confirm them).
OVERLAP = 200
#: Core length of the first pass's windows (frames). Each window holds its banded factor (about
#: 29 KB a frame on the sample character) and (frames, K) iterates; measured on 36,000 frames of
#: the sample character: see docs/performance.md.
WINDOW_FRAMES = 6000
#: Half-width (frames) of the first window solved around each seam.
SEAM = 32


def residual_tolerance(scale, w):
    """The kernel's tolerance on the free residual: rounding level of the system's largest entry."""
    return 1e-12 * scale * max(1.0, float(np.abs(w).max(initial=0.0)))


def solve_temporal(A, C, G, R, lo, hi, lam, mu, *, max_iter=200, chunk=4096, pad=32, split=True, start=None):
    """Solve the whole take. Shapes as in ``engine_frames.solve_frames``; mu = (mu1, mu2) absolute.
    ``start`` (F, K): weights to start from instead of the per-frame guess (e.g. a per-frame solve
    the caller already has); only the work changes, not the optimum. Should the iteration not settle
    from ``start`` within ``max_iter``, it runs again from the per-frame guess. Takes of at least
    ``SPLIT_FRAMES`` frames (with ``split``) are solved in windows whose seams are settled exactly
    (``engine.windows``): the same optimum, in memory bounded by the window length.

    Returns (W (F, K), iterations, converged).
    """
    F, K = G.shape
    products = reusable(A, R, C)  # pattern Hessians kept from earlier solves, when asked (this thread's)
    if split and F >= SPLIT_FRAMES:
        return _solve_windows(A, C, G, R, lo, hi, lam, mu, products, max_iter, chunk, pad, start)
    w, it, ok, _ = _solve_piece(A, C, G, R, lo, hi, lam, temporal_operator(F, *mu), products, max_iter, chunk,
                                pad, start, None)
    return w, it, ok


def _solve_piece(A, C, G, R, lo, hi, lam, T, products, max_iter, chunk, pad, first, workers):
    """The kernel on one piece: a whole take, or a window of one (``T`` its temporal operator, ``G``
    with the held frames' coupling folded in). Starts from ``first`` if given (clipped), else from
    per-frame solves; should ``first`` not settle, again from those.
    Returns (W, iterations, converged, scale of the system)."""
    pats, inv = patterns(C)
    Hp = pattern_hessians(A, pats, R, products=products)

    def guess(first):
        """``first``, or per-frame solves (frames without data: their rest value)."""
        if first is not None:
            return np.clip(first, lo, hi)
        w = np.clip(0.0, lo, hi).astype(float)
        idx = np.flatnonzero(C.sum(axis=1) > 0)
        if idx.size:
            w[idx] = solve_frames(A, C[idx], G[idx], R, lo[idx], hi[idx], lam, max_iter=INIT_ITER, chunk=chunk,
                                  exact=False, workers=workers)[0]
        return w

    w, it, ok = _active_set(Hp, inv, G, lo, hi, lam, T, guess(first), max_iter, pad)
    if not ok and first is not None:
        # The active set can wander without settling from some starts (measured: a smooth start on
        # weakly observed shapes of the sample character); the per-frame guess is the start the
        # iteration is made for, so a given start that fails is dropped for it.
        w, more, ok = _active_set(Hp, inv, G, lo, hi, lam, T, guess(None), max_iter, pad)
        it += more
    return w, it, ok, _scale(Hp, T)


def _solve_windows(A, C, G, R, lo, hi, lam, mu, products, max_iter, chunk, pad, start):
    """The whole take in windows (``engine.windows``): cores in windows with free ends, then the seams."""
    F, K = G.shape
    edges = windows.cores(F, WINDOW_FRAMES)
    n = edges.size - 1
    W = np.empty((F, K))

    def run_cores(first, last, out):
        """Cores [first, last) one after the other, into ``out`` (their frames); (iterations, converged)."""
        its, oks = [0], [True]
        for i in range(first, last):
            a, b = max(0, int(edges[i]) - OVERLAP), min(F, int(edges[i + 1]) + OVERLAP)
            w, it, ok, _ = _solve_piece(A, C[a:b], G[a:b], R, lo[a:b], hi[a:b], lam, temporal_operator(b - a, *mu),
                                        products, max_iter, chunk, pad, None if start is None else start[a:b], 1)
            out[edges[i] - edges[first] : edges[i + 1] - edges[first]] = w[edges[i] - a : edges[i + 1] - a]
            its.append(it)
            oks.append(ok)
        return max(its), all(oks)

    def there():  # the child's half comes back as an array
        out = np.empty((edges[n] - edges[n // 2], K))
        return out, run_cores(n // 2, n, out)

    (it_a, ok_a), (wb, (it_b, ok_b)) = run_beside(lambda: run_cores(0, n // 2, W), there)
    W[edges[n // 2] :] = wb
    del wb
    it_s, ok_s = _settle_seams(A, C, G, R, lo, hi, lam, temporal_operator(F, *mu), products, max_iter, chunk, pad,
                               W, edges)
    return W, max(it_a, it_b) + it_s, ok_a and ok_b and ok_s


def _settle_seams(A, C, G, R, lo, hi, lam, T, products, max_iter, chunk, pad, W, edges):
    """Settle every seam of ``W`` in place (``engine.windows``); returns (iterations, converged)."""
    F = W.shape[0]
    seams = windows.Seams(edges, max(SEAM, 3), F)
    reach = windows.coupling(T)
    its, ok_all = [0], True
    while (span := seams.next()) is not None:
        a, b = span
        Gw = G[a:b] - windows.held_coupling(T, W, a, b)
        w, it, ok, scale = _solve_piece(A, C[a:b], Gw, R, lo[a:b], hi[a:b], lam, windows.window_operator(T, a, b),
                                        products, max_iter, chunk, pad, W[a:b], 1)
        left, right = windows.edge_changes(W[a:b], w, a, b, F)
        W[a:b] = w
        its.append(it)
        ok_all &= ok
        # the neighbours outside read the edge frames: moved beyond the tolerance, the window grows
        tol = residual_tolerance(scale, w)
        seams.settle(a, b, left * reach > tol, right * reach > tol)
    return max(its), ok_all


def _single_changes(changed, st_old, st_new, frames, pad):
    """The safeguard's step: of the wrong variables (``changed``, rows = ``frames``), only the first
    one of each group of frames closer than ``2 * pad`` changes, and a variable leaving a bound
    becomes free instead of jumping to the other bound (the single pivot of the complementarity
    problem; a direct jump measured a two-state cycle on weakly observed shapes with strong L1).
    Groups far apart barely interact (a change decays within ``pad`` frames), so they each take
    their step in the same iteration. Returns (changed, st_new)."""
    rows = np.flatnonzero(changed.any(axis=1))
    f = frames[rows]
    heads = rows[np.concatenate([[True], f[1:] - f[:-1] > 2 * pad])]
    one = np.zeros_like(changed)
    one[heads, np.argmax(changed[heads], axis=1)] = True
    jump = one & (st_old != FREE) & (st_new != FREE)
    return one, np.where(jump, FREE, st_new).astype(st_new.dtype)


#: First iteration whose classification goes through the trajectory predictor. The first one reads
#: the start (per-frame weights, not smoothed: most of the take changes); predicting from it
#: measured no fewer iterations at twice the predictor's cost, and two configurations of the
#: 24-case sweep slower. The predictor stops for good once an iteration fails to reduce the count
#: of wrong variables (the safeguard then takes over).
PREDICT_FROM = 2

#: Iterations allowed without fewer wrong variables than the best so far before the iteration
#: changes one variable at a time per group of frames (after Judice & Pires' safeguard). Plain
#: primal-dual active-set steps can cycle when Q is not an M-matrix, and second differences make
#: it one (measured on the sample character: two weights of one shape in neighbouring frames
#: swapping states with period 4, from any start).
SAFE_TRIES = 3


def _scale(Hp, T):
    """Largest entry of the system (within-frame and temporal)."""
    return float(np.abs(Hp).max() + np.abs(T[0]).max(initial=0.0))


def _active_set(Hp, inv, G, lo, hi, lam, T, w, max_iter, pad):
    """The primal-dual active-set iteration over frames with pattern Hessians ``Hp[inv]`` and the
    temporal operator ``T`` (``temporal_operator``, or a window's), from ``w``."""
    F, K = G.shape
    w = np.array(w, dtype=float)

    def qmul_rows(X, rows):
        return hmul_by_pattern(Hp, inv if rows is None else inv[rows], X)

    # per-variable proximal step 1 / Q_kk: a variable leaving a bound lands where its own curvature
    # puts it (a step from the mean curvature sent strong shapes from one bound straight to the other)
    curvature = np.maximum(np.einsum("nkk->nk", Hp)[inv] + T[0][:, None], 1e-300)  # Q_kk
    step = 1.0 / curvature
    scale = _scale(Hp, T)
    has_l1 = bool(np.any(lam > 0))
    with single_blas_thread():
        grad = qmul_rows(w, None) + _tmul(T, w) - G
        st, sg = classify(w - step * grad, step, lo, hi, lam)
        redo = np.ones(F, dtype=bool)  # frames whose state changed: their fixed variables move to the bound
        best, tries = np.inf, SAFE_TRIES  # fewest wrong variables so far; full changes left without progress
        predict = True  # the trajectory predictor, until an iteration fails to reduce the wrong count
        pending = np.zeros(F, dtype=bool)  # frames with wrong variables the safeguard left for later
        for it in range(1, max_iter + 1):
            free = st == FREE
            if redo.any():
                idx = np.flatnonzero(redo)
                target = np.where(free[idx], w[idx], fixed_values(st[idx], lo[idx], hi[idx]))
                moved = (target != w[idx]).any(axis=1)  # from a good start (joined halves): a few
                redo[idx[~moved]] = False
                idx = idx[moved]
                delta = np.zeros_like(w)
                delta[idx] = target[moved] - w[idx]
                w[idx] = target[moved]
                grad += _qdelta(qmul_rows, T, delta, redo)
            lin = lam * np.where(free, sg, 0.0) if has_l1 else 0.0
            tol = residual_tolerance(scale, w)
            w, grad, touched = _settle(context(Hp, inv, T, free), qmul_rows, T, G, w, grad, free, lin, tol, pad)
            # only frames whose w or grad moved can change state (early on: all of them, no gathers)
            near = touched | dilate(redo, 2) | pending
            idx = slice(None) if near.mean() > 0.9 else np.flatnonzero(near)
            frames = np.arange(F)[idx]  # the frames classified
            st_t, sg_t = classify(w[idx] - step[idx] * grad[idx], step[idx], lo[idx], hi[idx], lam)
            if has_l1:
                # A free weight whose sign changes stops at the kink 0 first: on shapes the markers
                # barely see, a direct jump to the other sign moves it across the whole flat
                # direction and back every iteration (measured: +-0.5 for a 3.6e-7 change).
                flip = (st[idx] == FREE) & (st_t == FREE) & (sg_t != sg[idx]) & (lam > 0)
                st_t[flip] = ZERO
            changed = st_t != st[idx]
            n_wrong = int(changed.sum())
            pending[:] = False  # every pending frame was in idx
            if not n_wrong:
                # counted as before: the final check is an iteration; free weights can sit a rounding
                # error outside their bounds (a weight at 0 under L1, a proximal point just inside)
                return np.clip(w, lo, hi), it + 1, True
            predict = predict and n_wrong < best
            if n_wrong < best:
                best, tries = n_wrong, SAFE_TRIES
            elif tries:
                tries -= 1
            else:  # no progress: one variable at a time (Murty's least-index rule), see _single_changes
                wrong = changed.any(axis=1)
                changed, st_t = _single_changes(changed, st[idx], st_t, frames, pad)
                st_t = np.where(changed, st_t, st[idx])
                sg_t = np.where(changed, sg_t, sg[idx])
                pending[frames[wrong & ~changed.any(axis=1)]] = True  # classified again next time
            if predict and it >= PREDICT_FROM:
                # runs of frames at a bound move as far as their own trajectory says (engine_trajectory)
                st_t, sg_t = predict_states(w[idx], grad[idx], st_t, sg_t, changed, curvature[idx], lo[idx],
                                            hi[idx], lam, T, frames)
                changed = st_t != st[idx]
            rows = changed.any(axis=1)
            redo = np.zeros(F, dtype=bool)
            redo[frames[rows]] = True
            st[idx], sg[idx] = st_t, sg_t
    return np.clip(w, lo, hi), max_iter, False  # active-set iterates can leave the box
