"""Whole-take temporal solve: against lsq_linear on the stacked sparse system, and its trade-off."""

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.optimize import lsq_linear

from facecap.solvers.engine import DEFAULT_SMOOTHING, basis_scale, solve_bounded
from test_engine_refs import localised_basis, take

TOL = 1e-6


def stacked_reference(A, D, C, R, l1, lo, hi, mu1, mu2, lock=None):
    """Build the whole-take least-squares system with scipy.sparse and solve it with BVLS."""
    F, P = D.shape
    K = A.shape[1]
    ok = (C > 0) & np.isfinite(D)
    blocks = [sp.block_diag([sp.csr_matrix(np.sqrt(C[f, ok[f]])[:, None] * A[ok[f]]) for f in range(F)])]
    rhs = [np.concatenate([np.sqrt(C[f, ok[f]]) * D[f, ok[f]] for f in range(F)])]
    blocks.append(sp.kron(sp.eye(F), sp.csr_matrix(np.linalg.cholesky(R).T)))
    rhs.append(np.zeros(F * K))
    eye = sp.eye(K)
    if mu1:
        D1 = sp.diags([-np.ones(F - 1), np.ones(F - 1)], [0, 1], shape=(F - 1, F))
        blocks.append(np.sqrt(mu1) * sp.kron(D1, eye))
        rhs.append(np.zeros((F - 1) * K))
    if mu2:
        D2 = sp.diags([np.ones(F - 2), -2 * np.ones(F - 2), np.ones(F - 2)], [0, 1, 2], shape=(F - 2, F))
        blocks.append(np.sqrt(mu2) * sp.kron(D2, eye))
        rhs.append(np.zeros((F - 2) * K))
    M = sp.vstack(blocks).tocsr()
    b = np.concatenate(rhs)
    lo = np.broadcast_to(lo, (F, K)).ravel().astype(float)
    hi = np.broadcast_to(hi, (F, K)).ravel().astype(float)
    assert np.all(lo >= 0), "reference handles L1 as a linear term only for lower >= 0"
    q = np.broadcast_to(l1, (F, K)).ravel()
    # locked variables: fold their columns into the right-hand side and drop them
    lk = np.full(F * K, np.nan) if lock is None else np.asarray(lock, float).ravel()
    fr = ~np.isfinite(lk)
    b = b - M[:, ~fr] @ lk[~fr]
    Mf = M[:, fr]
    z = sp.linalg.spsolve((Mf.T @ Mf).tocsc(), q[fr] / 2)
    x = lsq_linear(Mf.toarray(), b - Mf @ z, bounds=(lo[fr], hi[fr]), method="bvls", tol=1e-15).x
    w = lk.copy()
    w[fr] = x
    return w.reshape(F, K)


def floor(A):
    return 1e-12 * basis_scale(A) * np.eye(A.shape[1])


@pytest.mark.parametrize("mu", [(0.05, 0.0), (0.0, 0.05), (0.02, 0.1)])
def test_temporal_matches_stacked_bvls(mu):
    A = localised_basis(K=10)
    K = A.shape[1]
    W, D = take(A, F=60, seed=21)
    s = basis_scale(A)
    res = solve_bounded(A, D, regularisation=1e-4, smoothing=mu, relative=True)
    assert res.converged and res.mode == "temporal"
    ref = stacked_reference(A, D, np.isfinite(D).astype(float), 1e-4 * s * np.eye(K) + floor(A),
                            np.zeros(K), np.zeros(K), np.ones(K), mu[0] * s, mu[1] * s)
    np.testing.assert_allclose(res.weights, ref, atol=TOL, rtol=0)


def test_temporal_with_confidence_sparsity_bounds_locks_and_gap_frames():
    A = localised_basis(K=10)
    K = A.shape[1]
    W, D = take(A, F=60, seed=22)
    F = D.shape[0]
    D[30:33] = np.nan  # three frames with no data at all: bridged by the smoothing
    rng = np.random.default_rng(5)
    C = np.where(np.isfinite(D), rng.uniform(0.3, 1.5, size=D.shape), 0.0)
    s = basis_scale(A)
    hi = np.where(np.arange(K) % 2 == 0, 1.0, 0.7)
    locks = np.full((F, K), np.nan)
    locks[10:40, 3] = 0.2
    res = solve_bounded(A, D, mask=C, upper=hi, regularisation=1e-4, sparsity=0.02, locks=locks,
                        smoothing=(0.01, 0.05), relative=True)
    assert res.converged and res.solved.all()
    ref = stacked_reference(A, D, C, 1e-4 * s * np.eye(K) + floor(A), np.full(K, 0.02 * s),
                            np.zeros(K), hi, 0.01 * s, 0.05 * s, lock=locks)
    np.testing.assert_allclose(res.weights, ref, atol=TOL, rtol=0)
    assert np.all(res.weights[10:40, 3] == 0.2)


def _pulse_and_noise(mu):
    """Peak kept by a 3-frame lip closure at 60 fps, and second-difference jitter ratio on a noisy hold."""
    A = localised_basis(K=12, seed=3)
    K = A.shape[1]
    F = 120
    W = np.zeros((F, K))
    W[:, 2] = 0.3  # a held expression
    W[59:62, 5] = 0.8  # lips pressed for 3 frames (50 ms at 60 fps), below the bound
    rng = np.random.default_rng(9)
    clean = W @ A.T
    peak_pf = solve_bounded(A, clean, regularisation=1e-3, relative=True).weights[59:62, 5].max()
    peak_t = solve_bounded(A, clean, regularisation=1e-3, smoothing=mu, relative=True).weights[59:62, 5].max()
    noisy = clean + rng.normal(0, 5e-4, size=clean.shape)
    jit = lambda w: np.sqrt(np.mean(np.diff(w, n=2, axis=0) ** 2))  # noqa: E731
    j_pf = jit(solve_bounded(A, noisy, regularisation=1e-3, relative=True).weights)
    j_t = jit(solve_bounded(A, noisy, regularisation=1e-3, smoothing=mu, relative=True).weights)
    return peak_t / peak_pf, j_t / j_pf


def test_default_smoothing_trade_off():
    kept, jitter = _pulse_and_noise(DEFAULT_SMOOTHING)
    print(f"default smoothing {DEFAULT_SMOOTHING}: 3-frame closure keeps {kept:.1%} of its peak; "
          f"second-difference jitter is {jitter:.1%} of per-frame (drop {1 - jitter:.1%})")
    assert kept >= 0.90
    assert jitter <= 0.50


@pytest.mark.parametrize("fork", [True, False])
def test_split_take_matches_the_stacked_reference(monkeypatch, fork):
    """A take cut in two halves (one in a forked child where possible) and joined: still the optimum."""
    from facecap.solvers.engine import split as engine_split, temporal as engine_temporal

    monkeypatch.setattr(engine_temporal, "SPLIT_FRAMES", 30)
    monkeypatch.setattr(engine_temporal, "OVERLAP", 6)
    if not fork:
        monkeypatch.setattr(engine_split, "fork_available", lambda: False)
    A = localised_basis(K=10)
    K = A.shape[1]
    W, D = take(A, F=60, seed=23)
    D[28:31] = np.nan  # frames with no data right at the seam
    s = basis_scale(A)
    res = solve_bounded(A, D, regularisation=1e-4, sparsity=0.02, smoothing=(0.01, 0.05), relative=True)
    assert res.converged
    ref = stacked_reference(A, D, np.isfinite(D).astype(float), 1e-4 * s * np.eye(K) + floor(A),
                            np.full(K, 0.02 * s), np.zeros(K), np.ones(K), 0.01 * s, 0.05 * s)
    np.testing.assert_allclose(res.weights, ref, atol=TOL, rtol=0)


def test_long_take_split_and_windows_agree_with_one_piece(monkeypatch):
    """1,500 frames: the windowed iteration (incremental gradient) with and without the split agree,
    and the result meets the optimality conditions."""
    from facecap.solvers.engine import temporal as engine_temporal

    A = localised_basis(K=10)
    W, D = take(A, F=1500, seed=24)
    kw = dict(regularisation=1e-4, sparsity=0.01, smoothing=(0.0, 0.3), relative=True)
    monkeypatch.setattr(engine_temporal, "SPLIT_FRAMES", 10**9)
    one = solve_bounded(A, D, **kw)
    monkeypatch.setattr(engine_temporal, "SPLIT_FRAMES", 500)
    two = solve_bounded(A, D, **kw)
    assert one.converged and two.converged
    np.testing.assert_allclose(two.weights, one.weights, atol=1e-9, rtol=0)
    # KKT (half the objective's gradient): 0 on free weights, >= 0 at the lower bound, <= 0 at the upper
    s = basis_scale(A)
    C = np.isfinite(D)
    Dz = np.where(C, D, 0.0)
    w = one.weights
    g = ((w @ A.T) * C - Dz) @ A + w @ (1e-4 * s * np.eye(A.shape[1]) + floor(A))
    d2 = np.diff(w, n=2, axis=0)
    g[:-2] += 0.3 * s * d2
    g[1:-1] -= 2 * 0.3 * s * d2
    g[2:] += 0.3 * s * d2
    g += 0.5 * 0.01 * s  # the L1 term on w >= 0 (the kernel minimises half the objective)
    scale = np.abs(A.T @ A).max()
    free = (w > 1e-12) & (w < 1 - 1e-12)
    assert np.abs(g[free]).max() <= 1e-9 * scale
    at_lo, at_hi = w <= 1e-12, w >= 1 - 1e-12
    assert at_lo.sum() > 500  # the bounds are active: a test of the active set, not of a linear solve
    assert g[at_lo].min() >= -1e-9 * scale and g[at_hi].max(initial=0.0) <= 1e-9 * scale


def kkt_violation(A, C, G, R, lo, hi, lam, mu, w):
    """Largest violation of the optimality conditions of the whole-take problem at ``w``, relative
    to the gradient's scale: an optimality certificate that does not depend on how ``w`` was found.
    L1 is the true |w| (a kink at 0 on shapes whose range contains 0)."""
    from facecap.solvers.engine.temporal import _tmul, temporal_operator

    H = np.einsum("pk,fp,pl->fkl", A, C.astype(float), A) + R
    g = np.einsum("fkl,fl->fk", H, w) + _tmul(temporal_operator(len(w), *mu), w) - G  # smooth part
    assert np.all(w >= lo) and np.all(w <= hi)
    lam = np.broadcast_to(lam, w.shape)
    at_lo, at_hi, zero = w <= lo, w >= hi, (w == 0) & (lo < 0) & (hi > 0)
    up = np.where(w > 0, g + lam, np.where(w < 0, g - lam, g + lam))  # derivative moving up
    down = np.where(w < 0, g - lam, np.where(w > 0, g + lam, g - lam))  # ... moving down
    wrong = np.where(
        at_lo, np.maximum(-up, 0),
        np.where(at_hi, np.maximum(down, 0),
                 np.where(zero, np.maximum(np.maximum(-up, 0), np.maximum(down, 0)), np.abs(up))))
    return wrong.max() / np.abs(G).max()


def _cycle_take():
    from pathlib import Path

    d = np.load(Path(__file__).parent / "data" / "temporal_cycle.npz")
    G = d["G"]
    lo, hi = np.broadcast_to(d["lo"], G.shape), np.broadcast_to(d["hi"], G.shape)
    return d["A"], d["C"], G, d["R"], lo, hi, d["lam"], np.asarray(d["mu"])


def test_an_active_set_cycle_is_broken(monkeypatch):
    """60 frames of a long take of the sample character (second differences only): plain
    primal-dual active-set steps cycle with period 4 on one shape in four neighbouring frames, from
    any start. The safeguard (one variable at a time once the count of wrong variables stops
    falling) reaches the optimum."""
    from facecap.solvers.engine import temporal as engine_temporal

    A, C, G, R, lo, hi, lam, mu = _cycle_take()
    args = (A, C, G, R, lo, hi, lam, tuple(mu))
    w, it, ok = engine_temporal.solve_temporal(*args, split=False)
    assert ok and it <= 30
    assert kkt_violation(*args, w) < 1e-9

    # plain steps (no safeguard, no trajectory predictor): it cycles
    monkeypatch.setattr(engine_temporal, "SAFE_TRIES", 10**6)
    monkeypatch.setattr(engine_temporal, "PREDICT_FROM", 10**6)
    _, _, ok_plain = engine_temporal.solve_temporal(*args, split=False)
    assert not ok_plain


@pytest.mark.parametrize("l1, smooth, kink", [
    (1e3, 0.1, False), (1e3, 1.0, False), (1e4, 1.0, False), (1e4, 0.1, True),
    (1.0, 1.0, True), (1.0, 0.1, True), (1e3, 10.0, True),
])
def test_strong_sparsity_other_smoothing_and_kinks_settle(l1, smooth, kink):
    """The same 60 frames with L1 up to 10^4 times the default, smoothing 0.1-10 times, and the
    first 10 shapes on [-1, 1] (L1 is then |w|, a kink at 0). Each of these ran out of 40
    iterations before (strong shapes jumped from one bound straight to the other, weakly observed
    ones from one sign straight to the other); all reach the optimum now, the last one in the
    whole-take budget (200: the late iterations only re-solve windows)."""
    from facecap.solvers.engine import temporal as engine_temporal

    A, C, G, R, lo, hi, lam, mu = _cycle_take()
    lo = lo.copy()
    if kink:
        lo[:, :10] = -1.0
    args = (A, C, G, R, lo, hi, lam * l1, tuple(mu * smooth))
    w, it, ok = engine_temporal.solve_temporal(*args, split=False, max_iter=200 if smooth == 10.0 else 40)
    assert ok
    assert kkt_violation(*args, w) < 1e-9
