"""The whole-take kernel's trajectory predictor (solvers/engine_trajectory.py)."""

import numpy as np
import pytest

from facecap.solvers.engine import temporal as engine_temporal
from facecap.solvers.engine.frames import FREE, classify, fixed_values, solve_frames
from facecap.solvers.engine.temporal import _tmul, temporal_operator
from facecap.solvers.engine.trajectory import predict_states


def _beam_take(seed, F=600, mu2=1e-2):
    """Four shapes, one barely seen by the markers and two alike, second-difference smoothing
    strong against the data: the per-frame solve holds long runs of frames at 0 that the smooth
    optimum leaves, the case where plain active-set steps shorten a run by one frame per iteration."""
    rng = np.random.default_rng(seed)
    P, K = 12, 4
    A = rng.normal(size=(P, K)) * 0.1
    A[:, 3] *= 0.05
    A[:, 2] = A[:, 1] * 0.9 + A[:, 2] * 0.3
    t = np.arange(F)
    W = np.stack([0.5 + 0.5 * np.sin(t / 30.0), np.clip(np.sin(t / 17.0), 0, None) * 0.8,
                  np.clip(np.cos(t / 23.0), 0, None) * 0.5, 0.05 + 0.05 * np.cos(t / 11)], axis=1)
    D = W @ A.T + rng.normal(scale=0.003, size=(F, P))
    C = np.ones((F, P))
    R = np.eye(K) * 1e-7
    lo, hi = np.zeros((F, K)), np.ones((F, K))
    return A, C, D @ A, R, lo, hi, np.zeros(K), (0.0, mu2)


@pytest.mark.parametrize("seed", range(4))
def test_long_runs_at_a_bound_settle_in_a_few_iterations(seed, monkeypatch):
    """From the per-frame solve, plain steps need 12-22 iterations (one frame of a run per
    iteration); with the predictor at most 8, and both reach the same optimum."""
    from test_engine_temporal import kkt_violation

    A, C, G, R, lo, hi, lam, mu = args = _beam_take(seed)
    start = solve_frames(A, C, G, R, lo, hi, lam)[0]
    w, it, ok = engine_temporal.solve_temporal(*args, split=False, start=start)
    assert ok and it <= 8
    assert kkt_violation(*args, w) < 1e-9

    monkeypatch.setattr(engine_temporal, "PREDICT_FROM", 10**6)
    w_plain, it_plain, ok_plain = engine_temporal.solve_temporal(*args, split=False, start=start)
    assert ok_plain and it_plain >= it + 5  # measured: 12-22 against 5-7
    np.testing.assert_allclose(w, w_plain, atol=1e-6)


def _dense_window_check(Hdiag, T, frames, w, grad, lo, hi, lam, state, sign, mask):
    """Rebuild the windows' problem densely from frame numbers, solve it for the predicted active
    set, and check that the predicted states are its fixed point (free weights inside their
    bounds, fixed ones pushed against them): the predicted set is the windows' optimum."""
    diag, off1, off2 = T
    rows, ks = np.nonzero(mask)
    n = rows.size
    f = frames[rows]
    Q = np.diag(Hdiag[rows, ks])
    for i in range(n):
        for j in range(n):
            if i != j and ks[i] == ks[j]:
                a, b = min(f[i], f[j]), max(f[i], f[j])
                Q[i, j] = off1[a] if b - a == 1 else off2[a] if b - a == 2 else 0.0
    w0, g0 = w[rows, ks], grad[rows, ks]
    lo0, hi0, lam0 = lo[rows, ks], hi[rows, ks], lam[ks]
    st, sg = state[rows, ks], sign[rows, ks]
    free = st == FREE
    d = np.where(free, 0.0, fixed_values(st, lo0, hi0) - w0)
    rhs = -(g0 + Q @ d + lam0 * np.where(free, sg, 0.0))
    d[free] = np.linalg.solve(Q[np.ix_(free, free)], rhs[free])
    x = w0 + d
    assert np.all(x[free] >= lo0[free] - 1e-12) and np.all(x[free] <= hi0[free] + 1e-12)
    step = 1.0 / np.diag(Q)
    st_check, _ = classify((x - step * (g0 + Q @ d))[None], step[None], lo0[None], hi0[None], lam0[None])
    np.testing.assert_array_equal(st_check[0], st)


@pytest.mark.parametrize("skip", [False, True])
def test_predicted_windows_are_each_solved_exactly(skip):
    """Windows around changes, including two one frame apart (coupled through the frame between)
    and two separated by two frames (independent); ``skip``: the rows handed over are not all the
    take's frames (the kernel classifies only frames near a change), so rows next to each other
    may be frames apart."""
    A, C, G, R, lo, hi, lam, mu = _beam_take(0, F=120)
    F, K = G.shape
    T = temporal_operator(F, *mu)
    rng = np.random.default_rng(7)
    w = np.clip(solve_frames(A, C, G, R, lo, hi, lam)[0] + rng.normal(scale=0.05, size=G.shape), lo, hi)
    Hdiag = np.einsum("pk,pk->k", A, A)[None] + np.diag(R)[None] + T[0][:, None]
    grad = w @ (A.T @ A + R) + _tmul(T, w) - G
    frames = np.concatenate([np.arange(0, 60), np.arange(66, F)]) if skip else np.arange(F)
    state, sign = classify(w - grad / Hdiag, 1.0 / Hdiag, lo, hi, lam)
    state, sign = state[frames], sign[frames]
    changed = np.zeros((frames.size, K), dtype=bool)
    for r, k in [(10, 3), (18, 3), (30, 1), (39, 1), (57, 3), (62, 3), (80, 0)]:
        changed[r, k] = True
    pad = 3
    new_state, new_sign = predict_states(w[frames], grad[frames], state, sign, changed, Hdiag[frames], lo[frames],
                                         hi[frames], lam, T, frames, pad=pad)
    mask = changed.copy()
    for s in range(1, pad + 1):
        mask[s:] |= changed[:-s]
        mask[:-s] |= changed[s:]
    np.testing.assert_array_equal(new_state[~mask], state[~mask])  # outside the windows: untouched
    assert (new_state[mask] != state[mask]).any()  # the case moves some states
    _dense_window_check(Hdiag[frames], T, frames, w[frames], grad[frames], lo[frames], hi[frames], lam, new_state,
                        new_sign, mask)
