"""Engine kernels on their own: the numpy box QP of the exact fallback against BVLS, and the
segment-wise banded Cholesky of the temporal kernel against a dense solve."""

import numpy as np
import pytest
from scipy.optimize import lsq_linear

from facecap.solvers.engine_banded import context, frame_band, solve_window
from facecap.solvers.engine_frames import box_qp
from facecap.solvers.engine_temporal import temporal_operator


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


def test_exact_fallback_does_not_import_scipy():
    import subprocess
    import sys

    code = (
        "import sys, numpy as np\n"
        "from facecap.solvers.engine_frames import exact_frame\n"
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
