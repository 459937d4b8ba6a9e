"""Per-frame engine options against scipy's BVLS (`lsq_linear(method="bvls")`), frame by frame.

Reference construction: locked shapes are eliminated, the ridge R becomes rows chol(R)', a linear
term q'w (L1 on a one-signed range, cross terms with locked shapes) is absorbed by shifting the
right-hand side (||Mw - b||^2 + q'w = ||Mw - (b - Mz)||^2 + const with M'M z = q/2), and an L1
term on a range containing 0 is handled by enumerating orthants (BVLS in each, keep the best).
"""

import itertools

import numpy as np
import pytest
from scipy.optimize import lsq_linear

from facecap.solvers import FacecapError
from facecap.solvers.engine import basis_scale, solve_bounded

TOL = 1e-6


def objective(A, d, c, R, l1, w):
    ok = c > 0
    r = A[ok] @ w - d[ok]
    return float(np.sum(c[ok] * r * r) + w @ R @ w + np.sum(l1 * np.abs(w)))


def reference_frame(A, d, c, R, l1, lo, hi, lock=None):
    """Exact minimiser of sum c (Aw - d)^2 + w'Rw + sum l1 |w| on [lo, hi] with locks, via BVLS."""
    K = A.shape[1]
    lock = np.full(K, np.nan) if lock is None else lock
    L = np.isfinite(lock)
    Fr = ~L
    ok = (c > 0) & np.isfinite(d)
    sc = np.sqrt(c[ok])
    vL = lock[L]
    Af = A[ok][:, Fr]
    dd = d[ok] - A[ok][:, L] @ vL
    Rf = R[np.ix_(Fr, Fr)]
    q0 = 2 * R[np.ix_(Fr, L)] @ vL
    M = np.vstack([sc[:, None] * Af, np.linalg.cholesky(Rf).T])
    b0 = np.concatenate([sc * dd, np.zeros(Fr.sum())])
    l, h, lm = lo[Fr], hi[Fr], l1[Fr]
    straddle = np.flatnonzero((l < 0) & (h > 0) & (lm > 0))
    best = None
    for signs in itertools.product((-1.0, 1.0), repeat=straddle.size):
        s = np.where(l >= 0, 1.0, np.where(h <= 0, -1.0, 0.0))
        lb, ub = l.copy(), h.copy()
        for j, sg in zip(straddle, signs):
            s[j] = sg
            (lb if sg > 0 else ub)[j] = 0.0
        q = q0 + lm * s
        z = np.linalg.solve(M.T @ M, q / 2)
        x = lsq_linear(M, b0 - M @ z, bounds=(lb, ub), method="bvls", tol=1e-15).x
        w = lock.copy()
        w[Fr] = x
        val = objective(A, d, c, R, l1, w)
        if best is None or val < best[0]:
            best = (val, w)
    return best[1]


def localised_basis(P_markers=40, K=14, dims=3, seed=0):
    """Blendshape-like basis: each shape moves a compact patch of markers smoothly."""
    rng = np.random.default_rng(seed)
    pos = rng.uniform(-1, 1, size=(P_markers, 2))
    centres = rng.uniform(-1, 1, size=(K, 2))
    radius = rng.uniform(0.3, 0.7, size=K)
    fall = np.exp(-((pos[None] - centres[:, None]) ** 2).sum(-1) / (2 * radius[:, None] ** 2))  # (K, M)
    direction = rng.normal(size=(K, 1, dims)) + 0.3 * rng.normal(size=(K, P_markers, dims))
    B = fall[:, :, None] * direction * 0.01  # metres
    return B.reshape(K, -1).T  # (P, K)


def take(A, F=60, gap=0.05, noise=2e-4, seed=1, lo=0.0, hi=1.0):
    rng = np.random.default_rng(seed)
    K = A.shape[1]
    W = np.clip(rng.normal(0.1, 0.45, size=(F, K)), lo, hi)
    D = W @ A.T + rng.normal(0, noise, size=(F, A.shape[0]))
    D[rng.random(D.shape) < gap] = np.nan
    return W, D


def check_frames(res, A, D, C, R, l1, lo, hi, lock=None, frames=None):
    F = D.shape[0]
    for f in frames if frames is not None else range(F):
        lk = None if lock is None else (lock[f] if np.ndim(lock) == 2 else lock)
        ref = reference_frame(A, D[f], C[f], R, l1, lo, hi, lk)
        np.testing.assert_allclose(res.weights[f], ref, atol=TOL, rtol=0, err_msg=f"frame {f}")


def floor(A):
    return 1e-12 * basis_scale(A) * np.eye(A.shape[1])


def test_confidence_per_shape_ridge_and_bounds():
    A = localised_basis()
    P, K = A.shape
    W, D = take(A)
    rng = np.random.default_rng(3)
    C = np.where(np.isfinite(D), rng.uniform(0.2, 2.0, size=D.shape), 0.0)
    ridge = rng.uniform(0, 3e-3, size=K) * basis_scale(A)
    lo = np.where(np.arange(K) % 3 == 0, -0.5, 0.0)
    hi = np.where(np.arange(K) % 4 == 0, 0.6, 1.0)
    res = solve_bounded(A, D, mask=C, lower=lo, upper=hi, regularisation=ridge)
    check_frames(res, A, D, C, np.diag(ridge) + floor(A), np.zeros(K), lo, hi)
    assert res.at_bound.sum() > 0 and res.fallback_frames == 0


def test_per_marker_confidence_with_dims():
    A = localised_basis()
    W, D = take(A)
    M = A.shape[0] // 3
    cm = np.random.default_rng(4).uniform(0.1, 1.0, size=(D.shape[0], M))
    res = solve_bounded(A, D, mask=cm, dims=3, regularisation=1e-3, relative=True)
    C = np.where(np.isfinite(D), np.repeat(cm, 3, axis=1), 0.0)
    R = 1e-3 * basis_scale(A) * np.eye(A.shape[1]) + floor(A)
    check_frames(res, A, D, C, R, np.zeros(A.shape[1]), np.zeros(A.shape[1]), np.ones(A.shape[1]))


def test_full_regularisation_matrix():
    A = localised_basis()
    K = A.shape[1]
    W, D = take(A)
    G = np.random.default_rng(5).normal(size=(K, K)) * 0.05
    R = G.T @ G * basis_scale(A)
    res = solve_bounded(A, D, regularisation=R)
    C = np.isfinite(D).astype(float)
    check_frames(res, A, D, C, R + floor(A), np.zeros(K), np.zeros(K), np.ones(K))


@pytest.mark.parametrize("l1", [1e-3, 2e-2])
def test_sparsity_on_nonnegative_shapes(l1):
    A = localised_basis()
    K = A.shape[1]
    W, D = take(A)
    res = solve_bounded(A, D, sparsity=l1, regularisation=1e-4, relative=True)
    s = basis_scale(A)
    C = np.isfinite(D).astype(float)
    check_frames(res, A, D, C, 1e-4 * s * np.eye(K) + floor(A), np.full(K, l1 * s), np.zeros(K), np.ones(K))
    plain = solve_bounded(A, D, regularisation=1e-4, relative=True)
    assert (res.weights == 0).sum() > (plain.weights == 0).sum()


def test_sparsity_on_shapes_that_straddle_zero():
    A = localised_basis(K=8)
    K = A.shape[1]
    W, D = take(A, lo=-1.0, seed=7)
    lo = np.where(np.arange(K) < 4, -1.0, 0.0)
    s = basis_scale(A)
    res = solve_bounded(A, D, lower=lo, sparsity=0.05, regularisation=1e-4, relative=True)
    C = np.isfinite(D).astype(float)
    check_frames(res, A, D, C, 1e-4 * s * np.eye(K) + floor(A), np.full(K, 0.05 * s), lo, np.ones(K))
    assert np.any(res.weights[:, :4] < 0) and np.any(res.weights[:, :4] == 0)


def test_exact_fallback_agrees(monkeypatch):
    """max_iter=1 sends most frames to the exact fallback, including the L1 sign search."""
    A = localised_basis(K=8)
    K = A.shape[1]
    W, D = take(A, lo=-1.0, seed=8)
    lo = np.where(np.arange(K) < 4, -1.0, 0.0)
    s = basis_scale(A)
    res = solve_bounded(A, D, lower=lo, sparsity=0.05, regularisation=1e-4, relative=True, max_iter=1)
    assert res.fallback_frames > 0
    C = np.isfinite(D).astype(float)
    check_frames(res, A, D, C, 1e-4 * s * np.eye(K) + floor(A), np.full(K, 0.05 * s), lo, np.ones(K))


def test_locks_static_and_per_frame():
    A = localised_basis()
    K = A.shape[1]
    W, D = take(A)
    F = D.shape[0]
    R = 1e-4 * basis_scale(A) * np.eye(K) + floor(A)
    C = np.isfinite(D).astype(float)
    res = solve_bounded(A, D, regularisation=1e-4, relative=True, locks={2: 0.7, 5: 0.0})
    lock = np.full(K, np.nan)
    lock[2], lock[5] = 0.7, 0.0
    assert np.all(res.weights[:, 2] == 0.7) and np.all(res.weights[:, 5] == 0.0)
    check_frames(res, A, D, C, R, np.zeros(K), np.zeros(K), np.ones(K), lock)

    keyed = np.full((F, K), np.nan)
    keyed[::3, 1] = np.linspace(0, 1, len(range(0, F, 3)))  # an animator's keys on every third frame
    keyed[10:20, 7] = 0.25
    res = solve_bounded(A, D, regularisation=1e-4, relative=True, locks=keyed)
    held = np.isfinite(keyed)
    assert np.array_equal(res.weights[held], keyed[held])
    check_frames(res, A, D, C, R, np.zeros(K), np.zeros(K), np.ones(K), keyed)


def test_symmetry_coupling():
    A = localised_basis()
    K = A.shape[1]
    W, D = take(A)
    pairs = [(0, 1), (4, 9)]
    s = basis_scale(A)
    gamma = 0.3
    res = solve_bounded(A, D, regularisation=1e-4, relative=True, symmetry=pairs, symmetry_weight=gamma)
    R = 1e-4 * s * np.eye(K) + floor(A)
    for a, b in pairs:
        e = np.zeros(K)
        e[a], e[b] = 1, -1
        R = R + gamma * s * np.outer(e, e)
    check_frames(res, A, D, np.isfinite(D).astype(float), R, np.zeros(K), np.zeros(K), np.ones(K))
    free = solve_bounded(A, D, regularisation=1e-4, relative=True)
    gap = lambda r: np.abs(r.weights[:, 0] - r.weights[:, 1]).mean()  # noqa: E731
    assert gap(res) < gap(free)


def test_regions_solve_from_their_own_coordinates():
    A = localised_basis()
    P, K = A.shape
    W, D = take(A)
    s = basis_scale(A)
    upper_shapes, lower_shapes = np.arange(0, 6), np.arange(6, 12)  # shapes 12, 13 are in no region
    upper_coords, lower_coords = np.arange(0, 60), np.arange(50, P)  # overlapping coordinate sets
    locks = {12: 0.4}
    res = solve_bounded(
        A, D, regularisation=1e-4, relative=True, locks=locks,
        regions=[(upper_shapes, upper_coords), (lower_shapes, lower_coords)],
    )
    assert np.all(res.weights[:, 12] == 0.4)  # locked, in no region: held at its lock
    assert np.all(res.weights[:, 13] == 0.0)  # unlocked, in no region: held at rest, never moves
    R = 1e-4 * s * np.eye(K) + floor(A)
    for shapes, coords in [(upper_shapes, upper_coords), (lower_shapes, lower_coords)]:
        var = np.concatenate([shapes, [12, 13]])
        Ar = A[np.ix_(coords, var)]
        lock = np.full(var.size, np.nan)
        lock[-2:] = [0.4, 0.0]
        for f in range(D.shape[0]):
            d = D[f, coords]
            ref = reference_frame(Ar, d, np.isfinite(d).astype(float), R[np.ix_(var, var)],
                                  np.zeros(var.size), np.zeros(var.size), np.ones(var.size), lock)
            np.testing.assert_allclose(res.weights[f, shapes], ref[: shapes.size], atol=TOL, rtol=0)


def test_everything_at_once():
    A = localised_basis(K=10)
    K = A.shape[1]
    W, D = take(A, F=40, seed=11)
    rng = np.random.default_rng(12)
    C = np.where(np.isfinite(D), rng.uniform(0.5, 1.5, size=D.shape), 0.0)
    s = basis_scale(A)
    ridge = rng.uniform(1e-4, 1e-2, size=K)
    lo = np.where(np.arange(K) == 3, -0.5, 0.0)
    l1 = np.full(K, 0.01)
    locks = np.full((D.shape[0], K), np.nan)
    locks[5:15, 6] = 0.5
    res = solve_bounded(A, D, mask=C, lower=lo, regularisation=ridge, sparsity=l1, locks=locks,
                        symmetry=[(0, 1)], symmetry_weight=0.1, relative=True)
    R = np.diag(ridge * s) + floor(A)
    R[0, 0] += 0.1 * s
    R[1, 1] += 0.1 * s
    R[0, 1] -= 0.1 * s
    R[1, 0] -= 0.1 * s
    check_frames(res, A, D, C, R, l1 * s, lo, np.ones(K), locks)


def test_bad_options_name_the_argument():
    A = np.eye(3)
    D = np.zeros((2, 3))
    cases = [
        (dict(mask=np.ones((2, 4))), "`mask` must have shape"),
        (dict(lower=np.zeros(4)), "`lower` must be"),
        (dict(regularisation=np.ones((2, 2))), "`regularisation` must be"),
        (dict(regularisation=-np.eye(3)), "positive semi-definite"),
        (dict(sparsity=-1.0), "`sparsity` must be >= 0"),
        (dict(locks={5: 0.1}), "`locks` keys"),
        (dict(locks=np.zeros((3, 3))), "`locks` must be"),
        (dict(regions=[([0, 1], [0, 1]), ([1, 2], [2])]), "shares shapes"),
        (dict(regions=[([0, 7], [0])]), "regions\\[0\\] shapes"),
        (dict(symmetry=[(0, 0)]), "`symmetry` must be pairs"),
        (dict(regions=[([0], [0]), ([1], [1])], symmetry=[(0, 1)]), "spans two regions"),
        (dict(smoothing=(1.0,)), "`smoothing` must be a pair"),
        (dict(smoothing=(-1.0, 0.0)), "`smoothing` must be a pair"),
    ]
    for kwargs, msg in cases:
        with pytest.raises(FacecapError, match=msg):
            solve_bounded(A, D, **kwargs)
