"""Validation and assembly for ``engine.solve_bounded``: checks every argument, then splits the
problem into regions and hands each to the per-frame or temporal kernel."""

from dataclasses import dataclass

import numpy as np

from ..errors import FacecapError
from .frames import solve_frames
from .result import SolveResult
from .split import release_freed_memory


@dataclass(frozen=True, eq=False)
class Problem:
    A: np.ndarray  # (P, K)
    D: np.ndarray  # (F, P), NaN in gaps (where C == 0; C may also be 0 elsewhere)
    C: np.ndarray  # (F, P) confidence, or bool visibility when no mask was given
    lo: np.ndarray  # (F, K)
    hi: np.ndarray  # (F, K)
    R: np.ndarray  # (K, K) incl. ridge floor and symmetry
    l1: np.ndarray  # (K,)
    lock: np.ndarray  # (F, K), NaN = free
    regions: tuple  # ((shapes, coords), ...)
    held: np.ndarray  # shape indices in no region
    mu: tuple  # (mu1, mu2), absolute
    binary: bool = False  # C is 0/1 (no mask given): A' (c * d) is A' d, d being 0 at gaps


def projected_data(D, C, A, binary, block=2048):
    """G = (c * d) A per frame, d taken as 0 where c == 0 (NaN gaps). In blocks of frames: no
    (F, P) temporary (the take's 69 MB one measured 13 ms slower, in fresh pages)."""
    G = np.empty((D.shape[0], A.shape[1]))
    for a in range(0, D.shape[0], block):
        c = C[a : a + block]
        d = np.where(c if binary else c > 0, D[a : a + block], 0.0)
        G[a : a + block] = (d if binary else c * d) @ A
    return G


def _array(x, name):
    try:
        return np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise FacecapError(f"`{name}` must be numeric; got {type(x).__name__}") from e


def _per_shape(x, name, F, K, *, allow_frames=True):
    a = _array(x, name)
    shapes = [(), (K,)] + ([(F, K)] if allow_frames else [])
    if a.shape not in shapes:
        want = " or ".join(str(s) if s else "a scalar" for s in shapes)
        raise FacecapError(f"`{name}` must be {want}; got shape {a.shape}")
    return np.broadcast_to(a, (F, K) if allow_frames else (K,))


def _compact(x):
    """(F, K) ``x`` as (1, K) where every row is the same by construction (a broadcast view)."""
    return x[:1] if x.shape[0] and x.strides[0] == 0 else x


def _block(x, rows):
    """Rows ``rows`` (a slice) of an (F, K) array, or ``x`` itself where it is one row for every frame."""
    return x if x.shape[0] == 1 else x[rows]


def _rows(x, rows):
    """``x[rows]`` for (F, K) bounds, still a broadcast view where every row is the same."""
    if isinstance(rows, slice) or x.strides[0]:
        return x[rows]
    return np.broadcast_to(x[:1], (rows.size, x.shape[1]))


def _mask(mask, finite, dims):
    F, P = finite.shape
    if mask is None:
        return finite  # visibility as bool: the kernels read it as confidence 0/1 (an eighth of the memory)
    m = _array(mask, "mask")
    shapes = [(F, P), (P,)]
    if dims:
        if P % dims:
            raise FacecapError(f"`dims`={dims} does not divide the {P} coordinates of `A`")
        M = P // dims
        shapes += [(F, M), (M,)]
        if m.shape in ((F, M), (M,)) and (F, M) != (F, P):
            m = np.repeat(m, dims, axis=-1)
    if m.shape not in [(F, P), (P,)]:
        raise FacecapError(f"`mask` must have shape {' or '.join(map(str, shapes))}; got {m.shape}")
    m = np.broadcast_to(m, (F, P))
    if not np.isfinite(m).all() or np.any(m < 0):
        raise FacecapError("`mask` must be finite and non-negative")
    return np.where(finite, m, 0.0)


def _locks(locks, F, K):
    """(F, K) lock values, NaN = free; read-only (a broadcast view unless they vary per frame)."""
    per_shape = np.full(K, np.nan)
    if locks is None:
        return np.broadcast_to(per_shape, (F, K))
    if isinstance(locks, dict):
        for k, v in locks.items():
            if not (isinstance(k, (int, np.integer)) and 0 <= k < K):
                raise FacecapError(f"`locks` keys must be shape indices in [0, {K}); got {k!r}")
            per_shape[k] = float(v)
        return np.broadcast_to(per_shape, (F, K))
    a = _array(locks, "locks")
    if a.shape not in ((K,), (F, K)):
        raise FacecapError(f"`locks` must be a {{index: value}} mapping or have shape ({K},) or ({F}, {K}); got {a.shape}")
    if np.isinf(a).any():
        raise FacecapError("`locks` values must be finite (NaN = free)")
    return np.broadcast_to(a, (F, K))


def _regularisation(x, K):
    a = _array(x, "regularisation")
    if a.shape == ():
        a = np.full(K, float(a))
    if a.shape == (K,):
        if np.any(a < 0):
            raise FacecapError("`regularisation` must be >= 0")
        return np.diag(a)
    if a.shape == (K, K):
        if not np.allclose(a, a.T, atol=1e-12 * max(1.0, np.abs(a).max())):
            raise FacecapError("`regularisation` as a (K, K) matrix must be symmetric")
        if np.linalg.eigvalsh(a).min() < -1e-10 * max(1.0, np.abs(a).max()):
            raise FacecapError("`regularisation` as a (K, K) matrix must be positive semi-definite")
        return a.copy()
    raise FacecapError(f"`regularisation` must be a scalar or have shape ({K},) or ({K}, {K}); got {a.shape}")


def _index(x, n, name):
    a = np.asarray(x)
    if a.dtype == bool:
        if a.shape != (n,):
            raise FacecapError(f"`{name}` as a boolean mask must have shape ({n},); got {a.shape}")
        return np.flatnonzero(a)
    if a.ndim != 1 or not np.issubdtype(a.dtype, np.integer) or (a.size and (a.min() < 0 or a.max() >= n)):
        raise FacecapError(f"`{name}` must be integer indices in [0, {n}) or a boolean mask of shape ({n},)")
    if np.unique(a).size != a.size:
        raise FacecapError(f"`{name}` must not repeat an index")
    return a


def build_problem(A, D, *, mask, lower, upper, regularisation, sparsity, locks, regions, symmetry,
                  symmetry_weight, smoothing, relative, dims, max_iter, chunk):
    A = _array(A, "A")
    if A.ndim != 2:
        raise FacecapError(f"`A` must have shape (P, K); got {A.shape}")
    P, K = A.shape
    if not np.isfinite(A).all():
        raise FacecapError("`A` must be finite")
    D = _array(D, "D")
    if D.ndim != 2 or D.shape[1] != P:
        raise FacecapError(f"`D` must have shape (F, {P}); got {D.shape}")
    finite = np.isfinite(D)
    if not finite.all() and np.isinf(D).any():
        raise FacecapError("`D` must be finite or NaN (gaps)")
    F = D.shape[0]
    C = _mask(mask, finite, dims)
    lo = _per_shape(lower, "lower", F, K)
    hi = _per_shape(upper, "upper", F, K)
    lo1, hi1 = _compact(lo), _compact(hi)  # checked once per distinct row
    if np.isnan(lo1).any() or np.isnan(hi1).any():
        raise FacecapError("`lower` and `upper` must not be NaN")
    if np.any(lo1 > hi1):
        raise FacecapError("`lower` must not exceed `upper`")
    if (max_iter is not None and int(max_iter) < 1) or int(chunk) < 1:
        raise FacecapError("`max_iter` and `chunk` must be >= 1")

    scale = float(np.mean(np.einsum("pk,pk->k", A, A))) or 1.0
    unit = scale if relative else 1.0
    R = _regularisation(regularisation, K) * unit
    l1 = _per_shape(sparsity, "sparsity", F, K, allow_frames=False) * unit
    if np.any(l1 < 0) or np.isnan(l1).any():
        raise FacecapError("`sparsity` must be >= 0")
    gamma = float(symmetry_weight) * unit
    if gamma < 0:
        raise FacecapError(f"`symmetry_weight` must be >= 0; got {symmetry_weight}")
    pairs = np.asarray(list(symmetry), dtype=np.int64).reshape(-1, 2) if len(symmetry) else np.zeros((0, 2), np.int64)
    if pairs.size and (pairs.min() < 0 or pairs.max() >= K or np.any(pairs[:, 0] == pairs[:, 1])):
        raise FacecapError(f"`symmetry` must be pairs (a, b) of distinct shape indices in [0, {K})")
    for a, b in pairs:
        R[a, a] += gamma
        R[b, b] += gamma
        R[a, b] -= gamma
        R[b, a] -= gamma
    R += 1e-12 * scale * np.eye(K)

    try:
        mu = tuple(float(v) for v in smoothing)
    except TypeError as e:
        raise FacecapError(f"`smoothing` must be a pair (mu1, mu2); got {smoothing!r}") from e
    if len(mu) != 2 or min(mu) < 0 or not np.isfinite(mu).all():
        raise FacecapError(f"`smoothing` must be a pair (mu1, mu2) of finite values >= 0; got {smoothing!r}")
    mu = (mu[0] * unit, mu[1] * unit)

    lock = _locks(locks, F, K)

    if regions is None:
        regs = ((np.arange(K), np.arange(P)),)
        held = np.zeros(0, dtype=np.int64)
    else:
        regs = []
        owner = np.full(K, -1)
        for i, reg in enumerate(regions):
            try:
                shapes, coords = reg
            except (TypeError, ValueError) as e:
                raise FacecapError(f"`regions[{i}]` must be a pair (shapes, coords)") from e
            s = _index(shapes, K, f"regions[{i}] shapes")
            c = _index(coords, P, f"regions[{i}] coords")
            if np.any(owner[s] >= 0):
                raise FacecapError(f"`regions[{i}]` shares shapes {np.flatnonzero(owner[s] >= 0).tolist()} with another region")
            owner[s] = i
            regs.append((s, c))
        regs = tuple(regs)
        held = np.flatnonzero(owner < 0)
        for a, b in pairs:
            if owner[a] != owner[b]:
                raise FacecapError(f"`symmetry` pair ({a}, {b}) spans two regions")
    return Problem(A, D, C, lo, hi, R, np.asarray(l1, float), lock, regs, held, mu, binary=mask is None)


#: Default active-set iteration budgets (``solve_bounded(max_iter=None)``).
FRAME_MAX_ITER, TEMPORAL_MAX_ITER = 40, 200


def run(prob, *, max_iter, chunk, start=None, exact=True):
    A, C, D = prob.A, prob.C, prob.D
    F, P = D.shape
    K = A.shape[1]
    temporal = prob.mu[0] > 0 or prob.mu[1] > 0
    if max_iter is None:
        max_iter = TEMPORAL_MAX_ITER if temporal else FRAME_MAX_ITER
    locked1 = np.isfinite(_compact(prob.lock))
    locked = np.broadcast_to(locked1, prob.lock.shape)
    any_lock = bool(locked1.any())
    # held values: lock value, else clip(0, lo, hi)
    hold = None
    if prob.held.size:
        held_lo, held_hi = prob.lo[:, prob.held], prob.hi[:, prob.held]
        hold = np.where(locked[:, prob.held], prob.lock[:, prob.held], np.clip(0.0, held_lo, held_hi))
    whole_take = (temporal and len(prob.regions) == 1 and prob.held.size == 0
                  and np.array_equal(prob.regions[0][0], np.arange(K)))
    W = None if whole_take else np.full((F, K), np.nan)  # a whole-take solve's result is used as it is
    if prob.held.size:
        W[:, prob.held] = hold
    solved_any = np.zeros(F, dtype=bool)
    iters = fallback = 0
    converged = True
    notes = []
    for shapes, coords in prob.regions:
        var = np.concatenate([shapes, prob.held])  # region shapes first, then held ones (fixed)
        nr = shapes.size
        every = coords.size == P and np.array_equal(coords, np.arange(P))  # no copies of (F, P) arrays
        Ar = A[:, var] if every else A[np.ix_(coords, var)]
        Cr = C if every else C[:, coords]
        Rr = prob.R[np.ix_(var, var)]
        whole = nr == K and np.array_equal(shapes, np.arange(K))  # one region of every shape, in order
        if whole and not any_lock:
            lo, hi = prob.lo, prob.hi  # the whole problem (read-only views): no (F, K) copies
        else:
            lo = np.where(locked[:, var], prob.lock[:, var], prob.lo[:, var])
            hi = np.where(locked[:, var], prob.lock[:, var], prob.hi[:, var])
            lo[:, nr:] = hold
            hi[:, nr:] = hold
        l1 = np.concatenate([prob.l1[shapes], np.zeros(prob.held.size)]) * 0.5
        G = projected_data(D if every else D[:, coords], Cr, Ar, prob.binary)
        has = Cr.sum(axis=1) > 0
        w0 = None
        if start is not None:  # frames or shapes it leaves NaN start from their rest value
            w0 = start if whole else start[:, var]
            if np.isnan(w0).any():
                w0 = np.where(np.isnan(w0), np.clip(0.0, lo, hi), w0)
        if temporal:
            if not has.any():
                continue
            from .temporal import solve_temporal  # loads scipy

            w, it, ok = solve_temporal(Ar, Cr, G, Rr, lo, hi, l1, prob.mu, max_iter=max_iter, chunk=chunk, start=w0)
            if W is None:  # the solve is the whole result: no (F, K) copy
                W = w
            else:
                W[:, shapes] = w[:, :nr]
            solved_any[:] = True
            converged &= ok
        else:
            idx = np.flatnonzero(has)
            if idx.size == 0:
                continue
            rows = slice(None) if idx.size == F else idx  # every frame has data: no (F, P) copies
            w, it, fb = solve_frames(Ar, Cr[rows], G[rows], Rr, _rows(lo, rows), _rows(hi, rows), l1,
                                     max_iter=max_iter, chunk=chunk, start=None if w0 is None else w0[rows],
                                     exact=exact)
            if whole:
                W[rows] = w
            else:
                W[idx[:, None], shapes[None, :]] = w[:, :nr]
            solved_any[idx] = True
            fallback += fb
        iters = max(iters, it)
        # locked shapes of frames with no data in this region still show their lock value
        if any_lock:
            miss = ~np.isfinite(W[:, shapes]) & locked[:, shapes]
            if miss.any():
                W[:, shapes] = np.where(miss, prob.lock[:, shapes], W[:, shapes])

    if W is None:  # no data at all
        W = np.full((F, K), np.nan)
    Wz = np.where(np.isnan(W), 0.0, W) if np.isnan(W).any() else W

    def residuals():  # (F, P): computed when first asked for (most callers never do)
        r = Wz @ A.T
        r -= D
        r[C == 0] = 0.0  # also every NaN of D
        return r

    def residual_rows(a, b):  # the same for frames [a, b)
        r = Wz[a:b] @ A.T
        r -= D[a:b]
        r[C[a:b] == 0] = 0.0
        return r

    lo, hi = _compact(prob.lo), _compact(prob.hi)  # bounds the same for every frame: (1, K), no (F, K) temporaries
    tol = 1e-9 * np.maximum(1.0, np.abs(hi - lo))
    free_shape = ~locked1
    if prob.held.size:
        free_shape[:, prob.held] = False
    at_bound = np.empty(F, dtype=np.intp)
    for a in range(0, F, 8192):  # in blocks of frames: no (F, K) temporaries
        s = slice(a, a + 8192)
        near = np.abs(Wz[s] - _block(lo, s)) <= _block(tol, s)
        near |= np.abs(Wz[s] - _block(hi, s)) <= _block(tol, s)
        at_bound[s] = (near & _block(free_shape, s)).sum(axis=1)
    at_bound[~solved_any] = 0
    if (~solved_any).any():
        notes.append(f"{int((~solved_any).sum())} frame(s) had no visible markers and were not solved")
    if not converged:
        notes.append(f"temporal solve did not settle within {max_iter} active-set iterations; weights are feasible but not optimal")
    release_freed_memory(F)  # on long takes: what the solve freed, before the next stage
    return SolveResult(
        W, residuals, at_bound, solved_any, iters, fallback, tuple(notes), converged,
        "temporal" if temporal else "per-frame", residual_rows,
    )
