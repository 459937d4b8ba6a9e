"""Starting a solve from an earlier one's weights (the pipeline's head refits): same optimum as a
cold start, per frame and over the whole take, whatever the start holds."""

import numpy as np
import pytest

from facecap.solvers import FacecapError
from facecap.solvers.engine import solve_bounded
from test_engine_refs import localised_basis, take


def refit_pair(seed, F=300, lo=0.0):
    """Deltas of a take and of the same take after a small head refit (a smooth drift per coordinate)."""
    A = localised_basis(K=12, seed=seed)
    W, D = take(A, F=F, seed=seed + 1, lo=lo)
    drift = 3e-4 * np.sin(np.linspace(0, 3, F))[:, None] * np.random.default_rng(seed).normal(size=A.shape[0])
    return A, D, D + drift


@pytest.mark.parametrize("lo", [0.0, -1.0])  # -1: L1 on a range around 0 (the "kink" state)
def test_per_frame_start_reaches_the_cold_optimum(lo):
    A, D, D2 = refit_pair(3, lo=lo)
    kw = dict(lower=lo, regularisation=1e-4, sparsity=0.01, relative=True)
    before = solve_bounded(A, D, **kw)
    cold = solve_bounded(A, D2, **kw)
    warm = solve_bounded(A, D2, start=before.weights, **kw)
    np.testing.assert_allclose(warm.weights, cold.weights, atol=1e-10, rtol=0)
    assert warm.iterations <= cold.iterations


def test_temporal_start_reaches_the_cold_optimum(monkeypatch):
    from facecap.solvers.engine import temporal as engine_temporal

    A, D, D2 = refit_pair(4, F=900)
    kw = dict(regularisation=1e-4, sparsity=0.01, relative=True)
    per_frame = solve_bounded(A, D2, **kw)
    cold = solve_bounded(A, D2, smoothing=(0.0, 0.3), **kw)
    warm = solve_bounded(A, D2, smoothing=(0.0, 0.3), start=per_frame.weights, **kw)
    monkeypatch.setattr(engine_temporal, "SPLIT_FRAMES", 300)  # the halves start from it too
    split = solve_bounded(A, D2, smoothing=(0.0, 0.3), start=per_frame.weights, **kw)
    assert cold.converged and warm.converged and split.converged
    np.testing.assert_allclose(warm.weights, cold.weights, atol=1e-9, rtol=0)
    np.testing.assert_allclose(split.weights, cold.weights, atol=1e-9, rtol=0)


def test_start_with_gaps_out_of_range_values_and_locks():
    """NaN (no earlier value), values outside the bounds and locked shapes in the start are all fine."""
    A, D, D2 = refit_pair(5)
    F, K = D.shape[0], A.shape[1]
    locks = np.full((F, K), np.nan)
    locks[:, 2] = 0.4
    kw = dict(regularisation=1e-4, sparsity=0.01, relative=True, locks=locks)
    start = solve_bounded(A, D, **kw).weights.copy()
    start[::7] = np.nan
    start[1::5, 0] = 3.0
    start[2::5, 1] = -2.0
    for smoothing in ((0.0, 0.0), (0.0, 0.3)):
        cold = solve_bounded(A, D2, smoothing=smoothing, **kw)
        warm = solve_bounded(A, D2, smoothing=smoothing, start=start, **kw)
        np.testing.assert_allclose(warm.weights, cold.weights, atol=1e-9, rtol=0)
        assert np.all(warm.weights[:, 2] == 0.4)


def test_start_of_the_wrong_shape_is_named():
    A, D, _ = refit_pair(6, F=20)
    with pytest.raises(FacecapError, match=r"`start` must have shape \(F, K\) = \(20, 12\)"):
        solve_bounded(A, D, start=np.zeros((20, 11)))


def _wandering_start():
    """300 frames of a long take of the sample character and a smooth (interpolated) start."""
    from pathlib import Path

    d = np.load(Path(__file__).parent / "data" / "temporal_wandering_start.npz")
    G = d["G"]
    lo, hi = np.broadcast_to(d["lo"], G.shape), np.broadcast_to(d["hi"], G.shape)
    return (d["A"], d["C"], G, d["R"], lo, hi, d["lam"], tuple(d["mu"])), d["start"]


def test_a_smooth_start_settles():
    """From this start the active set used to wander for all 40 iterations on the weakly observed
    shapes (a proximal step from the frame's mean curvature; sign changes straight across 0). With
    per-variable steps and stops at the kink it settles like the per-frame guess does."""
    from facecap.solvers.engine import temporal as engine_temporal

    args, start = _wandering_start()
    w, it, ok = engine_temporal.solve_temporal(*args, split=False, start=start)
    ref, it_ref, ok_ref = engine_temporal.solve_temporal(*args, split=False)
    assert ok and ok_ref and it <= 20 and it_ref <= 20
    np.testing.assert_allclose(w, ref, atol=1e-9, rtol=0)


def test_a_start_that_does_not_settle_is_dropped_for_the_guess(monkeypatch):
    """Should the iteration not settle from a given start, the solve starts again from the
    per-frame guess and reaches the optimum (the first run is made to report failure here)."""
    from facecap.solvers.engine import temporal as engine_temporal

    args, start = _wandering_start()
    settled = []
    active_set = engine_temporal._active_set

    def first_fails(*a, **k):
        w, it, ok = active_set(*a, **k)
        settled.append(ok)
        return (w + 0.1, it, False) if len(settled) == 1 else (w, it, ok)

    monkeypatch.setattr(engine_temporal, "_active_set", first_fails)
    w, it, ok = engine_temporal.solve_temporal(*args, split=False, start=start)
    assert len(settled) == 2 and ok
    monkeypatch.setattr(engine_temporal, "_active_set", active_set)
    ref, _, _ = engine_temporal.solve_temporal(*args, split=False)
    np.testing.assert_allclose(w, ref, atol=1e-9, rtol=0)


def test_a_quick_prediction_is_feasible_and_near_the_optimum():
    """``exact=False`` with 2 iterations (the head refits' prediction): no exact fallback, every
    weight inside its bounds, and the fit to the markers within 1 % of the optimum's."""
    A, D, _ = refit_pair(6, F=600, lo=-1.0)
    kw = dict(lower=-1.0, regularisation=1e-4, sparsity=0.01, relative=True)
    best = solve_bounded(A, D, **kw)
    quick = solve_bounded(A, D, max_iter=2, exact=False, **kw)
    exact = solve_bounded(A, D, max_iter=2, **kw)
    assert quick.fallback_frames == 0 and exact.fallback_frames > best.fallback_frames
    np.testing.assert_allclose(exact.weights, best.weights, atol=1e-9, rtol=0)  # the fallback is exact
    assert np.all(quick.weights >= -1.0) and np.all(quick.weights <= 1.0)
    assert not np.allclose(quick.weights, best.weights, atol=1e-6)  # unsettled frames kept their iterate
    rms = lambda r: np.sqrt(np.nanmean(r.residuals ** 2))  # noqa: E731
    assert rms(quick) <= 1.01 * rms(best)
