"""Long takes solved in windows (``engine.windows``): the same optimum as the whole take in one
piece (weights within 1e-5, and the whole take's optimality conditions at every frame), with
locks, gaps, frames without data across a seam, bounds, sparsity and kinks; the memory of the
solve grows with the window, not with the take."""

import tracemalloc

import numpy as np
import pytest

from facecap.solvers.engine import solve_bounded
from facecap.solvers.engine import setup as engine_setup, split as engine_split, temporal as engine_temporal
from facecap.solvers.engine import windows as engine_windows
from test_engine_refs import localised_basis

#: The requirement: windowed weights within this of the unwindowed optimum.
AGREE = 1e-5


def smooth_take(A, F, seed, lo=0.0, hi=1.0, gap=0.05):
    """Smooth weights (events of 10-80 frames) with per-coordinate gaps, noise 0.2 mm."""
    rng = np.random.default_rng(seed)
    K = A.shape[1]
    t = np.arange(F)
    W = np.zeros((F, K))
    for k in range(K):
        for c in rng.uniform(0, F, size=max(1, F // 60)):
            width = rng.uniform(10, 80)
            W[:, k] += rng.uniform(0.2, 1.0) * np.exp(-0.5 * ((t - c) / (width / 4)) ** 2)
    W = np.clip(W + (lo < 0) * rng.normal(0, 0.2, size=(F, K)) * (rng.random(K) < 0.3), lo, hi)
    D = W @ A.T + rng.normal(0, 2e-4, size=(F, A.shape[0]))
    D[rng.random(D.shape) < gap] = np.nan
    return D


def windowed(monkeypatch, *, window=120, overlap=10, seam=4, split_frames=100):
    monkeypatch.setattr(engine_temporal, "SPLIT_FRAMES", split_frames)
    monkeypatch.setattr(engine_temporal, "WINDOW_FRAMES", window)
    monkeypatch.setattr(engine_temporal, "OVERLAP", overlap)
    monkeypatch.setattr(engine_temporal, "SEAM", seam)


def one_piece(monkeypatch):
    monkeypatch.setattr(engine_temporal, "SPLIT_FRAMES", 10**9)


def kkt_violation(A, C, G, R, lo, hi, lam, mu, w):
    """Largest violation of the whole take's optimality conditions at ``w``, relative to the
    gradient's scale (as ``test_engine_temporal.kkt_violation``; locked weights, lo == hi, excluded)."""
    from facecap.solvers.engine.temporal import _tmul, temporal_operator

    H = np.einsum("pk,fp,pl->fkl", A, C, A) + R
    g = np.einsum("fkl,fl->fk", H, w) + _tmul(temporal_operator(len(w), *mu), w) - G
    assert np.all(w >= lo) and np.all(w <= hi)
    lam = np.broadcast_to(lam, w.shape)
    at_lo, at_hi, zero = w <= lo, w >= hi, (w == 0) & (lo < 0) & (hi > 0)
    up = np.where(w > 0, g + lam, np.where(w < 0, g - lam, g + lam))
    down = np.where(w < 0, g - lam, np.where(w > 0, g + lam, g - lam))
    wrong = np.where(
        at_lo, np.maximum(-up, 0),
        np.where(at_hi, np.maximum(down, 0),
                 np.where(zero, np.maximum(np.maximum(-up, 0), np.maximum(down, 0)), np.abs(up))))
    wrong[lo == hi] = 0.0
    return wrong.max() / np.abs(G).max()


def certificate(A, D, res, *, reg, l1, mu, lower=0.0, upper=1.0, locks=None, mask=None):
    """The whole take's KKT violation at ``res.weights`` (the kernel's problem, rebuilt)."""
    prob = engine_setup.build_problem(
        A, D, mask=mask, lower=lower, upper=upper, regularisation=reg, sparsity=l1, locks=locks, regions=None,
        symmetry=(), symmetry_weight=0.0, smoothing=mu, relative=True, dims=None, max_iter=None, chunk=4096)
    locked = np.isfinite(prob.lock)
    lo = np.where(locked, prob.lock, prob.lo)
    hi = np.where(locked, prob.lock, prob.hi)
    C = prob.C.astype(float)
    G = engine_setup.projected_data(prob.D, prob.C, prob.A, prob.binary)
    return kkt_violation(prob.A, C, G, prob.R, lo, hi, prob.l1 * 0.5, prob.mu, res.weights)


CASES = {
    "plain": dict(reg=1e-4, l1=0.01, mu=(0.0, 0.3)),
    "first and second differences": dict(reg=1e-4, l1=0.003, mu=(0.05, 0.3)),
    "bounds and kinks": dict(reg=1e-4, l1=0.02, mu=(0.01, 0.1), lower=-0.5, upper=0.8),
    "strong smoothing": dict(reg=1e-3, l1=0.001, mu=(0.0, 3.0)),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_windows_agree_with_the_whole_take(monkeypatch, case):
    kw = CASES[case]
    A = localised_basis(K=10, seed=4)
    F = 700
    D = smooth_take(A, F, seed=len(case), lo=kw.get("lower", 0.0))
    D[118:126] = np.nan  # frames with no data at all, right across the first seam (at 117)
    opts = dict(regularisation=kw["reg"], sparsity=kw["l1"], smoothing=kw["mu"], relative=True,
                lower=kw.get("lower", 0.0), upper=kw.get("upper", 1.0))
    one_piece(monkeypatch)
    ref = solve_bounded(A, D, **opts)
    windowed(monkeypatch)
    got = solve_bounded(A, D, **opts)
    assert ref.converged and got.converged
    err = np.abs(got.weights - ref.weights).max()
    print(f"{case}: max |windowed - whole take| = {err:.2e}")
    assert err <= AGREE
    assert certificate(A, D, got, **kw) < 1e-9


def test_locks_confidence_and_per_frame_bounds_across_seams(monkeypatch):
    A = localised_basis(K=10, seed=6)
    F, K = 600, 10
    D = smooth_take(A, F, seed=9)
    rng = np.random.default_rng(2)
    mask = np.where(np.isfinite(D), rng.uniform(0.3, 1.5, size=D.shape), 0.0)
    locks = np.full((F, K), np.nan)
    locks[90:160, 3] = 0.2  # an animator's keys held across the seam at 120
    locks[:, 7] = 0.05  # a shape held for the whole take
    upper = np.where(np.arange(K) % 2, 0.7, 1.0)
    opts = dict(mask=mask, upper=upper, locks=locks, regularisation=1e-4, sparsity=0.02, smoothing=(0.01, 0.2),
                relative=True)
    one_piece(monkeypatch)
    ref = solve_bounded(A, D, **opts)
    windowed(monkeypatch, window=120, overlap=6, seam=3)
    got = solve_bounded(A, D, **opts)
    assert got.converged
    np.testing.assert_allclose(got.weights, ref.weights, atol=AGREE, rtol=0)
    assert np.all(got.weights[90:160, 3] == 0.2) and np.all(got.weights[:, 7] == 0.05)
    assert certificate(A, D, got, reg=1e-4, l1=0.02, mu=(0.01, 0.2), upper=upper, locks=locks, mask=mask) < 1e-9


def test_without_overlap_the_seams_do_the_work(monkeypatch):
    """Windows with no overlap at all (free ends right at the seams): the seam windows have real
    corrections to make, and grow until their edges stay put."""
    A = localised_basis(K=10, seed=7)
    D = smooth_take(A, 800, seed=11)
    opts = dict(regularisation=1e-4, sparsity=0.01, smoothing=(0.0, 1.0), relative=True)
    one_piece(monkeypatch)
    ref = solve_bounded(A, D, **opts)
    windowed(monkeypatch, window=100, overlap=0, seam=3)
    monkeypatch.setattr(engine_split, "fork_available", lambda: False)  # every solve counted here
    solves = []
    real = engine_temporal._solve_piece

    def counted(*a, **k):
        solves.append(a[2].shape[0])
        return real(*a, **k)

    monkeypatch.setattr(engine_temporal, "_solve_piece", counted)
    got = solve_bounded(A, D, **opts)
    np.testing.assert_allclose(got.weights, ref.weights, atol=AGREE, rtol=0)
    n_cores = 8
    assert len(solves) > n_cores + (n_cores - 1)  # some seam windows were solved again, wider
    assert max(solves[n_cores:]) > 2 * 3


def test_a_long_stretch_without_data_across_a_seam(monkeypatch):
    """300 frames without any data across a seam: only the smoothing bridges them, so the seam's
    window grows over the whole stretch."""
    A = localised_basis(K=8, seed=8)
    D = smooth_take(A, 900, seed=12)
    D[200:500] = np.nan  # seams at 150, 300, 450, ...
    opts = dict(regularisation=1e-4, sparsity=0.005, smoothing=(0.0, 0.5), relative=True)
    one_piece(monkeypatch)
    ref = solve_bounded(A, D, **opts)
    windowed(monkeypatch, window=150, overlap=20, seam=4)
    got = solve_bounded(A, D, **opts)
    assert got.converged and got.solved.all()
    np.testing.assert_allclose(got.weights, ref.weights, atol=AGREE, rtol=0)


@pytest.mark.skipif(not engine_split.fork_available(), reason="no fork on this platform")
def test_the_same_bits_with_and_without_the_second_process(monkeypatch):
    A = localised_basis(K=10, seed=5)
    D = smooth_take(A, 500, seed=13)
    opts = dict(regularisation=1e-4, sparsity=0.01, smoothing=(0.0, 0.3), relative=True)
    windowed(monkeypatch)
    forked = solve_bounded(A, D, **opts)
    monkeypatch.setattr(engine_split, "fork_available", lambda: False)
    here = solve_bounded(A, D, **opts)
    assert np.array_equal(forked.weights, here.weights) and forked.iterations == here.iterations


def test_seam_bookkeeping():
    seams = engine_windows.Seams(np.array([0, 100, 200, 300]), 10, 300)
    assert seams.spans == [[90, 110, False], [190, 210, False]]
    seams.settle(90, 110, False, False)
    assert seams.next() == (190, 210)
    seams.settle(190, 210, True, False)  # doubled to the left only
    assert seams.spans == [[90, 110, True], [170, 210, False]]
    seams.settle(170, 210, True, True)
    assert seams.spans == [[90, 110, True], [130, 250, False]]
    seams.settle(130, 250, True, False)  # reaches the first window: merged with it, unsettled again
    assert seams.spans == [[10, 250, False]]
    T = engine_temporal.temporal_operator(10, 0.1, 0.3)
    diag, o1, o2 = engine_windows.window_operator(T, 3, 7)
    assert diag.size == 4 and o1.size == 3 and o2.size == 2 and np.array_equal(diag, T[0][3:7])
    # the held frames' coupling is the part of the whole operator's product outside the window
    w = np.random.default_rng(0).normal(size=(10, 2))
    full = engine_temporal._tmul(T, w)[3:7]
    inside = engine_temporal._tmul((diag, o1, o2), w[3:7])
    np.testing.assert_allclose(inside + engine_windows.held_coupling(T, w, 3, 7), full, atol=1e-15)


def _peak_bytes(A, D, opts):
    tracemalloc.start()
    try:
        solve_bounded(A, D, **opts)
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_memory_grows_with_the_window_not_the_take(monkeypatch):
    """Peak memory of the solve (numpy's allocations, inputs included) for a take and for one four
    times as long: in windows, the growth is the take's own (F, P) / (F, K) arrays only; in one
    piece it is several times more (the banded factor and iterates of every frame)."""
    A = localised_basis(P_markers=30, K=16, seed=3)
    opts = dict(regularisation=1e-4, sparsity=0.01, smoothing=(0.0, 0.3), relative=True)
    short, long_ = (smooth_take(A, F, seed=14) for F in (1500, 6000))
    monkeypatch.setattr(engine_split, "fork_available", lambda: False)  # all of it in this process
    windowed(monkeypatch, window=500, overlap=40, seam=8)
    grow_windowed = _peak_bytes(A, long_, opts) - _peak_bytes(A, short, opts)
    one_piece(monkeypatch)
    grow_whole = _peak_bytes(A, long_, opts) - _peak_bytes(A, short, opts)
    per_frame = (grow_windowed / 4500, grow_whole / 4500)
    print(f"peak growth per frame: windows {per_frame[0]:.0f} B, one piece {per_frame[1]:.0f} B")
    # what any solve holds per frame: D, C, G, W and the result's bookkeeping (P = 90, K = 16)
    P, K = A.shape
    held = 8 * P + P + 8 * K * 4
    assert grow_windowed <= 2.0 * held * 4500
    assert grow_whole >= 2.5 * grow_windowed
