"""Per-frame kernel of the engine: many small box/L1 quadratic programmes, solved together.

Every frame f solves::

    minimise  1/2 w' H_f w - g_f' w + sum_k lam_k |w_k|   subject to  lo_f <= w <= hi_f

with ``H_f = A' diag(c_f) A + R``. ``H_f`` only depends on the frame's confidence pattern ``c_f``,
so it is formed once per distinct pattern (per chunk of frames), and its inverse is a low-rank update
of the full-visibility one (``FullInverse``). The iteration is a primal-dual
active-set / semi-smooth Newton method on the proximal fixed point
``w = clip(soft(w - s grad, s lam), lo, hi)``: each variable is either fixed (at ``lo``, ``hi`` or at
the L1 kink 0) or free with a known sign, and the free variables solve a linear system, or, when
fewer shapes are fixed than free, the fixed ones solve for their multipliers with ``H^-1``
(``Hinv_BB m = x_B - u_B``, u the unconstrained optimum). Frames only re-solve while their state
changes; the systems are gathered by size and solved in batches of exactly that size, so a frame
costs O(min(free, fixed)^3), not O(K^3). Frames that have not settled after ``max_iter``
iterations go to an exact per-frame fallback (``engine.exact``: a BVLS-style primal active set in
plain numpy, with a finite sign search for L1 on shapes whose range contains 0): per-frame solves
need no scipy, which Blender does not ship. The state codes and classification are ``engine.states``.

Inputs are trusted (validated by ``engine.solve_bounded``). Locked shapes arrive as lo == hi.
"""

import os
import threading
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from contextvars import ContextVar

import numpy as np

from .batched import hmul, solve_free
from .exact import box_qp, exact_frame  # noqa: F401  (box_qp re-exported: the fallback's kernel)
from .states import FREE, classify, fixed_values, start_state
from .threads import single_blas_thread


def patterns(C):
    """Distinct rows of C: (unique rows (n_pat, P), inverse (F,))."""
    C = np.ascontiguousarray(C)
    if C.shape[0] == 0:
        return C[:0], np.zeros(0, dtype=np.intp)
    binary = C.dtype == bool or bool(np.all((C == 0) | (C == 1)))
    key = np.packbits(C > 0, axis=1) if binary else C
    key = np.ascontiguousarray(key)
    view = key.view(np.dtype((np.void, key.dtype.itemsize * key.shape[1]))).ravel()
    _, first, inverse = np.unique(view, return_index=True, return_inverse=True)
    return C[first], inverse.reshape(-1)


def pattern_hessians(A, pats, R, H_full=None, products=None, out=None):
    """H_p = A' diag(c_p) A + R for each pattern, via the full-visibility matrix where cheaper;
    ``products`` (from ``reusable``): taken from / kept in the active ``reuse_pattern_setup``."""
    if products is not None:
        return products.hessians(A, pats, R, H_full)
    n = pats.shape[0]
    if H_full is None:
        H_full = A.T @ A + R
    miss = 1.0 - pats
    out = np.empty((n, A.shape[1], A.shape[1])) if out is None else out
    for i in range(n):
        nz = np.flatnonzero(miss[i])
        if nz.size == 0:
            out[i] = H_full
        elif nz.size * 2 < A.shape[0]:
            An = A[nz]
            out[i] = H_full - An.T @ (miss[i, nz, None] * An)
        else:
            out[i] = A.T @ (pats[i, :, None] * A) + R
    return out


#: Condition proxy ``max|H| * max|H^-1|`` below which a pattern's inverse is trusted (dual form,
#: and the low-rank update below).
WELL_CONDITIONED = 1e8


class FullInverse:
    """The full-visibility inverse ``H^-1`` (H = A'A + R) and what a gap pattern's inverse is updated
    from. A binary pattern missing the coordinates m has ``H_p = H - A_m' A_m``, so (Woodbury)
    ``H_p^-1 = H^-1 + V_m' (I - V_m A_m')^-1 V_m`` with ``V = A H^-1``: an r x r solve and a
    K x r x K product for r missing coordinates instead of a K x K inverse. Measured on the
    benchmark take (2-7 of 80 markers missing per pattern): 2.5x faster than ``np.linalg.inv``.
    ``usable`` is False when H itself is ill-conditioned (the update would lose the digits)."""

    def __init__(self, A, H_full):
        self.A = A
        self.Hinv = np.linalg.inv(H_full)
        self.usable = bool(np.abs(H_full).max() * np.abs(self.Hinv).max() < WELL_CONDITIONED)
        self.V = A @ self.Hinv


def pattern_inverses(Hp, pats=None, full=None):
    """(H_p^-1, whether the dual form may use it) for each pattern. With the patterns and a
    ``FullInverse`` of the same A and R, binary patterns missing at most K/2 coordinates are
    updated from it (each pattern's result depends on that pattern only, whatever the batch)."""
    K = Hp.shape[1]
    if full is None or not full.usable or pats is None:
        Hinv = np.linalg.inv(Hp)
    else:
        missing = pats == 0
        r = missing.sum(axis=1)
        update = ((pats == 1) | missing).all(axis=1) & (r <= K // 2)
        Hinv = np.empty_like(Hp)
        direct = np.flatnonzero(~update)
        if direct.size:
            Hinv[direct] = np.linalg.inv(Hp[direct])
        for size in np.unique(r[update]).tolist():
            sel = np.flatnonzero(update & (r == size))
            if size == 0:
                Hinv[sel] = full.Hinv
                continue
            m = np.argsort(~missing[sel], axis=1, kind="stable")[:, :size]  # the missing coordinates
            Vm = full.V[m]
            S = np.eye(size) - Vm @ full.A[m].transpose(0, 2, 1)  # not a P x P table: P may be large
            Hinv[sel] = full.Hinv + Vm.transpose(0, 2, 1) @ np.linalg.solve(S, Vm)
    # The fixed-set ("dual") form solves with Hinv_BB, |B| = fixed count: cheaper than H_FF when
    # fewer shapes are fixed than free, and accurate while H is well conditioned.
    ok = np.abs(Hp).max(axis=(1, 2)) * np.abs(Hinv).max(axis=(1, 2)) < WELL_CONDITIONED
    if full is not None and full.usable and pats is not None and not ok.all():
        bad = np.flatnonzero(~ok & update)  # an update loses more digits there: invert directly
        Hinv[bad] = np.linalg.inv(Hp[bad])
        ok[bad] = np.abs(Hp[bad]).max(axis=(1, 2)) * np.abs(Hinv[bad]).max(axis=(1, 2)) < WELL_CONDITIONED
    return Hinv, ok


_REUSE = ContextVar("facecap_pattern_setup", default=None)


#: Bytes of pattern products a ``PatternSetup`` keeps by default (Hessian and inverse: 2 K^2 floats a
#: pattern): every pattern of a 10-minute take of the sample character (8,519 patterns, 368 MB);
#: none of a take whose patterns do not all fit (they are computed per chunk, as without reuse).
REUSE_BYTES = 400 << 20


class PatternSetup:
    """Products kept by ``reuse_pattern_setup``: one ``_Products`` per exact (A, R), at most
    ``max_bytes`` of them in all (each kept pattern books room for its Hessian and its inverse)."""

    def __init__(self, max_bytes=REUSE_BYTES):
        self.lock = threading.Lock()
        self.problems = {}
        self.room = int(max_bytes)

    def book(self, n, K, whole=False):
        """Room for up to ``n`` more patterns of K shapes; returns how many fit (with ``whole``: all
        of them, or none)."""
        with self.lock:
            fit = max(0, min(int(n), self.room // (2 * K * K * 8)))
            if whole and fit < n:
                fit = 0
            self.room -= fit * 2 * K * K * 8
            return fit


@contextmanager
def reuse_pattern_setup(setup=None):
    """Within it, solves keep and reuse each confidence pattern's Hessian, inverse and condition
    flag, keyed by the pattern and the exact (A, R) the kernel sees; results are bit-identical.

    Why: the pipeline solves one take three times (two head refits, the final temporal solve) with
    the same A, R and gaps; only the data changes, and most of a quick refit is this setup. Measured
    on the 36,000-frame sample take (8,519 patterns; 5 interleaved runs, medians): second refit
    1.34 -> 0.95 s, first 1.69 -> 1.81 s (it stores them), whole pipeline 12.7 -> 12.2 s wall and
    15.6 -> 14.1 s CPU; the temporal solve takes its Hessians without a copy.

    Scoped, not global: the products (two K x K floats per pattern: 2 x 184 MB there; the Hessians
    replace the temporal solve's own) live as long as ``setup`` (a ``PatternSetup``; default: a new
    one, dropped on exit; pass one to share it across several ``with`` blocks), and are bounded by
    its ``max_bytes``: on longer takes the patterns beyond it are computed where needed, as
    without reuse (the same bits either way). Without ``setup``, a nested use shares the outer one. Per thread/task (a
    context variable): solves elsewhere in the same process do not see it. Yields the setup.
    """
    if setup is None and _REUSE.get() is not None:
        yield _REUSE.get()
        return
    setup = PatternSetup() if setup is None else setup
    token = _REUSE.set(setup)
    try:
        yield setup
    finally:
        _REUSE.reset(token)


def reusable(A, R, C):
    """The active ``reuse_pattern_setup``'s products for this A, R (and confidence dtype), or None.
    Call it in the solving thread: worker threads do not inherit the context."""
    setup = _REUSE.get()
    if setup is None:
        return None
    # exact bytes (and layout) rather than a hash: equal keys then mean bit-identical products
    key = (A.shape, A.strides, R.shape, R.strides, np.dtype(C.dtype).str, A.tobytes(), R.tobytes())
    with setup.lock:
        return setup.problems.setdefault(key, _Products(setup))


class _Blocks:
    """Rows kept in the blocks they were computed in: adding never copies (fresh arrays of hundreds
    of MB cost, in page faults, about what reusing saves)."""

    def __init__(self):
        self.blocks = []
        self.where = np.zeros((0, 2), np.intp)  # per row: (block, index in it); -1: not computed

    def grow(self, n):
        """Room for ``n`` rows (a new array: snapshots taken earlier stay valid)."""
        self.where = np.concatenate([self.where, np.full((n - self.where.shape[0], 2), -1, np.intp)])

    def add(self, rows, data):
        self.blocks.append(data)
        self.where[rows, 0] = len(self.blocks) - 1
        self.where[rows, 1] = np.arange(rows.size)

    def snapshot(self, rows):
        """What ``gather`` needs for ``rows`` (take it under the lock; gather outside it)."""
        return list(self.blocks), self.where[rows]

    @staticmethod
    def gather(snap):
        blocks, loc = snap
        b, i = loc[:, 0], loc[:, 1]
        if b.size == 0:
            return blocks[0][:0]
        first = blocks[b[0]]
        if (b == b[0]).all():
            if i.size == first.shape[0] and np.array_equal(i, np.arange(i.size)):
                return first  # the rows of one block, in order: no copy
            return first[i]
        out = np.empty((b.size,) + first.shape[1:], first.dtype)
        for k in np.unique(b).tolist():
            m = b == k
            out[m] = blocks[k][i[m]]
        return out


def _spans(n, size=512):
    """[a, b) slices of range(n) of about ``size``: a few MB of temporaries each, which the heap
    reuses (one slice of thousands measured 2x slower, in page faults)."""
    cuts = np.linspace(0, n, -(-n // size) + 1).astype(int).tolist()
    return list(zip(cuts[:-1], cuts[1:]))


class _Products:
    """Per-pattern setup products of one (A, R): each pattern's H, and its inverse and ``ok`` flag
    once a per-frame solve asked, found by the pattern's bytes. Each is computed on its own, so it
    is bit-identical to a per-chunk computation, and never changes once stored. Patterns are kept
    while the ``PatternSetup``'s room lasts."""

    def __init__(self, setup=None):
        self.lock = threading.Lock()
        self.setup = PatternSetup() if setup is None else setup
        self.index = {}  # pattern bytes -> row
        self.declined = False  # the take's patterns did not all fit: none is kept
        self.H, self.Hinv = _Blocks(), _Blocks()
        self.ok = np.zeros(0, bool)

    def keep(self, A, pats, R, H_full=None, inverses=False, map_=map, full=None, whole=False):
        """Compute and keep the products of ``pats`` not kept yet, while there is room; in slices
        mapped by ``map_`` (e.g. a thread pool's); inverses are updated from ``full`` (a
        ``FullInverse`` of this A, R; default: made here). ``whole``: ``pats`` are every pattern of
        the take; if they do not all fit, none is kept, now or later (on a long take a fraction of
        them would save little and hold the setup's whole budget). Returns the ``full`` used."""
        K = A.shape[1]
        with self.lock:
            keys = [p.tobytes() for p in pats]
            new = np.array([i for i, k in enumerate(keys) if k not in self.index], dtype=np.intp)
            new = new[: 0 if self.declined else self.setup.book(new.size, K, whole)]
            self.declined |= whole and new.size < sum(k not in self.index for k in keys)
            if inverses and full is None and (new.size or (self.Hinv.where[:, 0] < 0).any()):
                full = FullInverse(A, A.T @ A + R if H_full is None else H_full)
            if new.size:
                n0, n = len(self.index), len(self.index) + new.size
                pn = pats if new.size == len(keys) else pats[new]
                block = np.empty((new.size, K, K))  # one block: the temporal kernel can use it as is

                def fill(span):
                    pattern_hessians(A, pn[span[0] : span[1]], R, H_full, out=block[span[0] : span[1]])
                    return pattern_inverses(block[span[0] : span[1]], pn[span[0] : span[1]], full) if inverses else None

                spans = _spans(new.size)
                done = list(map_(fill, spans))
                block.flags.writeable = False  # shared from now on
                self.H.grow(n)
                self.Hinv.grow(n)
                self.H.add(np.arange(n0, n), block)
                self.index.update(zip((keys[i] for i in new.tolist()), range(n0, n)))
                self.ok = np.concatenate([self.ok, np.zeros(new.size, bool)])
                for (a, b), inv in zip(spans, done):
                    if inv is not None:
                        self.Hinv.add(np.arange(n0 + a, n0 + b), inv[0])
                        self.ok[n0 + a : n0 + b] = inv[1]
            if inverses:
                rows = np.fromiter((self.index.get(k, -1) for k in keys), dtype=np.intp, count=len(keys))
                need = rows >= 0
                need[need] = self.Hinv.where[rows[need], 0] < 0  # kept by a solve that needed no inverses (a temporal one)
                if need.any():
                    todo, pt = rows[need], pats[need]
                    Ht = _Blocks.gather(self.H.snapshot(todo))
                    spans = _spans(todo.size)

                    def invert(span):
                        return pattern_inverses(Ht[span[0] : span[1]], pt[span[0] : span[1]], full)

                    for (a, b), (Hi, ok) in zip(spans, map_(invert, spans)):
                        self.Hinv.add(todo[a:b], Hi)
                        self.ok[todo[a:b]] = ok
        return full

    def prepare(self, A, pats, R, H_full=None, inverses=False, full=None):
        """The products of ``pats`` in their order: (H (n, K, K), (Hinv, ok) or None); kept ones
        taken (without a copy when they are one kept block in order), new ones kept while there is
        room, the others computed here."""
        K = A.shape[1]
        full = self.keep(A, pats, R, H_full, inverses, full=full)
        with self.lock:
            rows = np.fromiter((self.index.get(p.tobytes(), -1) for p in pats), dtype=np.intp, count=pats.shape[0])
            kept = rows >= 0
            H = self.H.snapshot(rows[kept])
            Hi = (self.Hinv.snapshot(rows[kept]), self.ok[rows[kept]]) if inverses else None
        if kept.all():
            return _Blocks.gather(H), (None if Hi is None else (_Blocks.gather(Hi[0]), Hi[1]))
        Hp = np.empty((pats.shape[0], K, K))
        if kept.any():
            Hp[kept] = _Blocks.gather(H)
        Hp[~kept] = pattern_hessians(A, pats[~kept], R, H_full)
        if not inverses:
            return Hp, None
        if full is None:
            full = FullInverse(A, A.T @ A + R if H_full is None else H_full)
        Hinv, ok = np.empty_like(Hp), np.empty(pats.shape[0], bool)
        if kept.any():
            Hinv[kept], ok[kept] = _Blocks.gather(Hi[0]), Hi[1]
        Hinv[~kept], ok[~kept] = pattern_inverses(Hp[~kept], pats[~kept], full)
        return Hp, (Hinv, ok)

    def hessians(self, A, pats, R, H_full=None):
        return self.prepare(A, pats, R, H_full)[0]


def solve_frames(A, C, G, R, lo, hi, lam, *, max_iter=40, chunk=4096, workers=None, exact=True, start=None):
    """Solve every frame. C (F, P) confidences, G (F, K) = A' (c * d), lo/hi (F, K), lam (K,).
    ``start`` (F, K): weights of a similar earlier solve; each frame's first active set is read
    from it (fewer iterations, same optimum).

    Chunks of frames run on ``workers`` threads (default: CPU count, at most 4); BLAS is pinned to
    one thread meanwhile, since the work is many tiny solves (numpy releases the GIL in most of them:
    two threads measured as fast as two forked halves, and faster when the machine is shared).

    Returns (W (F, K), iterations, number of frames handed to the exact fallback).
    """

    F, K = G.shape
    W = np.empty((F, K))
    H_full = A.T @ A + R
    products = reusable(A, R, C)  # read here: the worker threads do not see the context
    workers = workers or min(4, os.cpu_count() or 1)
    n_chunks = -(-F // chunk)
    if workers > 1 and n_chunks > 1:
        n_chunks = -(-n_chunks // workers) * workers  # every thread gets as many chunks (no straggler)
    chunk = -(-F // n_chunks) if n_chunks else chunk  # even chunks

    full = None

    def one(first):
        sl = slice(first, min(first + chunk, F))
        pats, inv = patterns(C[sl])
        if products is None:
            Hp = pattern_hessians(A, pats, R, H_full)
            inverses = pattern_inverses(Hp, pats, full)
        else:  # this chunk's patterns, in its own order (the kernels' shapes and code paths as without)
            Hp, inverses = products.prepare(A, pats, R, H_full, inverses=True, full=full)
        state = None if start is None else start_state(start[sl], lo[sl], hi[sl], lam)
        w, it, bad, sign = _pdas(Hp, inv, G[sl], lo[sl], hi[sl], lam, max_iter, state, inverses)
        if bad.size and not exact:  # a starting guess is enough: clip the last iterate
            w[bad] = np.clip(w[bad], lo[sl][bad], hi[sl][bad])
        elif bad.size:
            g, l, h = G[sl], lo[sl], hi[sl]
            for i in bad:
                w[i] = exact_frame(Hp[inv[i]], g[i], l[i], h[i], lam, sign[i])
        W[sl] = w
        return it, bad.size if exact else 0

    with single_blas_thread():
        full = FullInverse(A, H_full)  # in here: the same bits whichever path computes an inverse
        if workers > 1 and n_chunks > 1:
            with ThreadPoolExecutor(workers) as pool:
                if products is not None:  # the take's patterns once, on the threads (chunks repeat them)
                    products.keep(A, patterns(C)[0], R, H_full, inverses=True, map_=pool.map, full=full, whole=True)
                out = list(pool.map(one, range(0, F, chunk)))
        else:
            out = [one(s) for s in range(0, F, chunk)]
    iters = max((o[0] for o in out), default=0)
    fallback = sum(o[1] for o in out)
    return W, iters, fallback


#: Active-set iterations without a settled frame after which a handful of remaining frames go to
#: the exact fallback.
STALL = 6


def _pdas(Hp, inv, g, lo, hi, lam, max_iter, state=None, inverses=None):
    """The active-set iteration for frames with Hessians ``Hp[inv]``; the first active set is
    ``state`` = (state, sign) if given, else read from the unconstrained optimum. ``inverses``:
    ``pattern_inverses(Hp)`` if the caller has them."""
    n, K = g.shape
    Hinv, ok = pattern_inverses(Hp) if inverses is None else inverses
    dual_ok = ok[inv]
    u0 = hmul(Hinv, inv, g)  # unconstrained optimum of the smooth part
    w = u0.copy()
    step = 1.0 / np.maximum(np.einsum("nkk->n", Hp) / K, 1e-300)[inv]
    grad = np.zeros_like(w)
    prev = prev_sg = None
    active = np.arange(n)
    sign = np.zeros((n, K))
    has_l1 = bool(np.any(lam > 0))
    it = last_drop = 0
    for it in range(1, max_iter + 1):
        ia = inv[active]
        if it == 1 and state is not None:
            st, sg = state
        else:
            st, sg = classify(w[active] - step[active, None] * grad, step[active], lo[active], hi[active], lam)
        if prev is not None:
            keep = ((st != prev) | ((st == FREE) & (sg != prev_sg) & (lam > 0))).any(axis=1)
            if not keep.all():
                last_drop = it
            active, st, sg, ia = active[keep], st[keep], sg[keep], ia[keep]
            if active.size == 0:
                return w, it, active, sign
            if it - last_drop >= STALL and active.size <= max(8, n // 500):
                # a few frames cycling between states (measured: 2-8 of 4000 for 30 iterations on
                # the sample character): the exact fallback is cheaper than waiting for max_iter
                return w, it, active, sign
        free = st == FREE
        xf = fixed_values(st, lo[active], hi[active])
        lin = lam * np.where(free, sg, 0.0) if has_l1 else None
        wa, grad = _equality_solve(Hp, Hinv, ia, free, xf, g[active], u0[active], lin, dual_ok[active])
        w[active] = wa
        sign[active] = np.where(free, sg, 0.0)
        prev, prev_sg = st, sg
    return w, it, active, sign


def _equality_solve(Hp, Hinv, ia, free, xf, g, u0, lin, dual_ok):
    """Per frame: w with w_B = xf_B minimising 1/2 w'Hw - q'w (q = g - lin); returns (w, Hw - g).

    Frames with fewer fixed than free shapes (and a well-conditioned H) solve for the multipliers
    of the fixed set, ``Hinv_BB m = xf_B - u_B`` with ``u = Hinv q``, then ``w = u + Hinv m``;
    the others solve ``H_FF w_F = q_F - H_FB xf_B``."""
    n, K = free.shape
    w = np.empty((n, K))
    grad = np.empty((n, K))
    nf = free.sum(axis=1)
    dual = dual_ok & (2 * nf > K)
    P = np.flatnonzero(~dual)
    if P.size:
        q = g[P] if lin is None else g[P] - lin[P]
        fx = np.where(free[P], 0.0, xf[P])
        away = np.flatnonzero(fx.any(axis=1))  # frames with a shape held away from 0 (most hold at 0)
        if away.size:
            q[away] -= hmul(Hp, ia[P][away], fx[away])
        wp = fx + solve_free(Hp, ia[P], free[P], q)
        w[P] = wp
        grad[P] = hmul(Hp, ia[P], wp) - g[P]
    Dn = np.flatnonzero(dual)
    if Dn.size:
        iD = ia[Dn]
        u = u0[Dn] if lin is None else u0[Dn] - hmul(Hinv, iD, lin[Dn])
        fixed = ~free[Dn]
        m = solve_free(Hinv, iD, fixed, xf[Dn] - u)
        w[Dn] = np.where(fixed, xf[Dn], u + hmul(Hinv, iD, m))
        grad[Dn] = m if lin is None else m - lin[Dn]
    return w, grad
