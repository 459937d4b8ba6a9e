"""Engine kernels on their own: the numpy box QP of the exact fallback against BVLS, the gap
patterns' inverses (low-rank updates of the full-visibility one) against ``np.linalg.inv``, and the
segment-wise banded Cholesky of the temporal kernel against a dense solve."""

import numpy as np
import pytest
from scipy.optimize import lsq_linear

from facecap.solvers.engine.banded import context, frame_band, solve_window
from facecap.solvers.engine.frames import FullInverse, box_qp, pattern_hessians, pattern_inverses
from facecap.solvers.engine.temporal import temporal_operator


@pytest.mark.parametrize("seed", range(6))
def test_box_qp_matches_bvls(seed):
    rng = np.random.default_rng(seed)
    n = 12
    M = rng.normal(size=(30, n)) * rng.uniform(0.1, 3, size=n)  # uneven column scales
    b = rng.normal(size=30) * 2
    lb = np.where(rng.random(n) < 0.3, -np.inf, rng.uniform(-1, 0, n))
    ub = np.where(rng.random(n) < 0.3, np.inf, rng.uniform(0, 1, n))
    ub[0] = lb[0] = 0.25  # a fixed variable
    x = box_qp(M.T @ M, M.T @ b, lb, ub)
    ref = np.r_[0.25, lsq_linear(M[:, 1:], b - 0.25 * M[:, 0], bounds=(lb[1:], ub[1:]), method="bvls", tol=1e-15).x]
    np.testing.assert_allclose(x, ref, atol=1e-9, rtol=0)
    assert np.all((x >= lb) & (x <= ub))


def _gap_patterns(P, n, rng, most_missing):
    pats = np.ones((n, P))
    for i in range(1, n):  # row 0: nothing missing
        pats[i, rng.choice(P, size=rng.integers(1, most_missing + 1), replace=False)] = 0.0
    return pats


def test_pattern_inverses_by_update_match_direct_inverses():
    from test_engine_refs import localised_basis

    rng = np.random.default_rng(3)
    A = localised_basis(P_markers=20, K=12, seed=4)  # 60 coordinates
    R = 1e-3 * np.eye(12) * np.mean(A * A) * 60
    pats = _gap_patterns(60, 40, rng, 6)  # 1-6 coordinates missing: updated
    pats = np.vstack([pats, _gap_patterns(60, 5, rng, 40)[1:]])  # up to 40 missing: some directly
    pats[-1, :3] = 0.5  # a weighted (non-binary) pattern: directly
    Hp = pattern_hessians(A, pats, R)
    H_full = A.T @ A + R
    Hinv, ok = pattern_inverses(Hp, pats, FullInverse(A, H_full))
    ref, ref_ok = pattern_inverses(Hp)
    scale = np.abs(ref).max(axis=(1, 2))[:, None, None]
    np.testing.assert_allclose(Hinv / scale, ref / scale, atol=1e-12, rtol=0)
    np.testing.assert_array_equal(ok, ref_ok)
    # each pattern's inverse is its own: the same bits in any batch
    one, _ = pattern_inverses(Hp[7:8], pats[7:8], FullInverse(A, H_full))
    assert np.array_equal(one[0], Hinv[7])


def test_ill_conditioned_patterns_are_inverted_directly():
    """A shape seen only by the missing markers leaves H_p nearly singular: the update would lose
    the digits, so such patterns are flagged (no dual form) and inverted directly."""
    rng = np.random.default_rng(5)
    A = rng.normal(size=(30, 6)) * 0.01
    A[:, 5] = 0.0
    A[:3, 5] = 0.01  # shape 5: coordinates 0-2 only
    R = 1e-12 * np.eye(6) * np.mean(A * A) * 30
    pats = np.ones((3, 30))
    pats[1, :3] = 0.0  # shape 5 unseen
    pats[2, 10:13] = 0.0
    Hp = pattern_hessians(A, pats, R)
    Hinv, ok = pattern_inverses(Hp, pats, FullInverse(A, A.T @ A + R))
    assert ok.tolist() == [True, False, True]
    assert np.array_equal(Hinv[1], np.linalg.inv(Hp[1]))
    np.testing.assert_allclose(Hp[2] @ Hinv[2], np.eye(6), atol=1e-9)


def test_exact_fallback_does_not_import_scipy():
    import subprocess
    import sys

    code = (
        "import sys, numpy as np\n"
        "from facecap.solvers.engine.frames import exact_frame\n"
        "H = np.array([[2.0, 0.5], [0.5, 1.0]])\n"
        "w = exact_frame(H, np.array([-1.0, 2.0]), np.zeros(2), np.ones(2), np.zeros(2))\n"
        "assert np.allclose(w, [0.0, 1.0]), w\n"
        "assert 'scipy.optimize' not in sys.modules, 'scipy.optimize imported'\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def _dense(Hp, inv, T, F, K):
    Q = np.zeros((F * K, F * K))
    d, o1, o2 = T
    for f in range(F):
        Q[f * K : (f + 1) * K, f * K : (f + 1) * K] = Hp[inv[f]] + d[f] * np.eye(K)
    for lag, off in ((1, o1), (2, o2)):
        for f in range(F - lag):
            blk = off[f] * np.eye(K)
            Q[(f + lag) * K : (f + lag + 1) * K, f * K : (f + 1) * K] += blk
            Q[f * K : (f + 1) * K, (f + lag) * K : (f + lag + 1) * K] += blk
    return Q


def _window_problem(mu=(0.3, 0.7)):
    rng = np.random.default_rng(0)
    F, K = 50, 6
    Hp = np.stack([(lambda M: M @ M.T + 0.1 * np.eye(K))(rng.normal(size=(K, K))) for _ in range(3)])
    inv = rng.integers(0, 3, F)
    T = temporal_operator(F, *mu)
    free = rng.random((F, K)) < 0.6
    free[10:14] = False  # frames with nothing free cut the coupling
    ctx = context(Hp, inv, T, free)
    r = rng.normal(size=free.sum())

    def dense_solve(a, b):
        sub = np.zeros((F, K), dtype=bool)
        sub[a:b] = free[a:b]
        idx = np.flatnonzero(sub.ravel())
        return np.linalg.solve(_dense(Hp, inv, T, F, K)[np.ix_(idx, idx)], r[ctx[3].offs[a] : ctx[3].offs[b]])

    return ctx, r, dense_solve


@pytest.mark.parametrize("a, b, seg", [(0, 50, 4), (0, 50, 7), (5, 40, 3), (0, 50, 100), (3, 20, 5), (20, 21, 3), (8, 16, 3)])
@pytest.mark.parametrize("mu", [(0.3, 0.7), (0.0, 0.5), (0.4, 0.0)])  # both lags, lag 2 dominant, lag 1 only
def test_banded_window_solve_matches_dense(a, b, seg, mu):
    ctx, r, dense_solve = _window_problem(mu)
    np.testing.assert_allclose(solve_window(ctx, r, a, b, seg=seg), dense_solve(a, b), atol=1e-12, rtol=0)


def test_windows_with_their_bands_built_together_match_dense():
    """The temporal kernel builds the within-frame bands of many small windows at once."""
    ctx, r, dense_solve = _window_problem()
    wins = [(0, 9), (15, 31), (33, 50)]
    frames = np.concatenate([np.arange(a, b) for a, b in wins])
    B, start = frame_band(ctx, frames)
    row = np.empty(50, dtype=np.int64)
    row[frames] = start
    for a, b in wins:
        np.testing.assert_allclose(solve_window(ctx, r, a, b, seg=4, band=(B, row)), dense_solve(a, b), atol=1e-12, rtol=0)
