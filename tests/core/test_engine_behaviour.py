"""Engine behaviour: cancellation with an imperfect basis, held shapes, statuses, diagnostics."""

import numpy as np
import pytest

from facecap.solvers.character.diagnostics import basis_conditioning, basis_warnings, residual_stats
from facecap.solvers.engine import solve_bounded
from test_engine_refs import localised_basis


def test_cancellation_bounded_beats_unconstrained_with_imperfect_basis():
    """Chuang & Bregler: with a basis that does not span the data, unconstrained weights cancel
    each other (large +/- pairs) to fit the markers, which wrecks the dense target; bounds stop it.

    20 overlapping shapes seen by 20 markers; the performer's shapes are the target's perturbed by
    25 % plus one shape the target lacks. Target vertex error = RMS of B_target (w - w_true) over
    400 dense points. Measured ratios bounded/unconstrained: 0.75, 0.65, 0.64 (seeds 0-2).
    """
    ratios = []
    for seed in range(3):
        rng = np.random.default_rng(seed)
        K, F = 20, 400
        B = localised_basis(P_markers=400, K=K, seed=seed)  # dense target points (3 * 400, K)
        A = B[: 3 * 20]  # the 20 bound markers
        W = np.clip(rng.normal(0.15, 0.35, size=(F, K)), 0, 1)
        A_actor = A * (1 + 0.25 * rng.normal(size=A.shape)) + 0.002 * rng.normal(size=A.shape)
        extra = localised_basis(P_markers=400, K=1, seed=99)[: A.shape[0], 0]
        D = W @ A_actor.T + np.outer(rng.uniform(0, 1, F), extra) + rng.normal(0, 2e-4, size=(F, A.shape[0]))
        bounded = solve_bounded(A, D, regularisation=1e-6, relative=True)
        free = solve_bounded(A, D, lower=-np.inf, upper=np.inf, regularisation=1e-6, relative=True)
        err = lambda w: np.sqrt(np.mean(((w - W) @ B.T) ** 2))  # noqa: E731
        e_b, e_u = err(bounded.weights), err(free.weights)
        print(f"seed {seed}: target-vertex RMS error bounded {e_b * 1e3:.3f} mm, unconstrained {e_u * 1e3:.3f} mm")
        assert e_b < e_u
        ratios.append(e_b / e_u)
    assert np.mean(ratios) <= 0.8


def test_locked_and_out_of_region_shapes_never_move():
    A = localised_basis()
    P, K = A.shape
    rng = np.random.default_rng(1)
    D = rng.uniform(0, 1, size=(50, K)) @ A.T  # data that wants every shape
    locks = np.full((50, K), np.nan)
    locks[:, 0] = 0.9
    locks[20:30, 4] = 0.1
    for smoothing in [(0.0, 0.0), (0.0, 0.5)]:
        r = solve_bounded(A, D, locks=locks, regions=[(np.arange(0, 8), np.arange(0, P // 2))],
                          lower=np.r_[np.full(8, 0.0), np.full(K - 8, 0.2)], smoothing=smoothing, relative=True)
        assert np.all(r.weights[:, 0] == 0.9)
        assert np.all(r.weights[20:30, 4] == 0.1)
        assert np.all(r.weights[:, 8:] == 0.2)  # outside the region: held at clip(0, lower, upper)
    # without locks: the region's shapes followed by the held ones are every shape in order, and
    # the held ones still do not move
    for smoothing in [(0.0, 0.0), (0.0, 0.5)]:
        r = solve_bounded(A, D, regions=[(np.arange(0, 8), np.arange(P))], lower=np.r_[np.full(8, 0.0), np.full(K - 8, 0.2)],
                          smoothing=smoothing, relative=True)
        assert np.all(r.weights[:, 8:] == 0.2)
        assert r.weights[:, :8].max() > 0.5


def test_non_convergence_is_a_status_not_an_exception():
    A = localised_basis(K=10)
    rng = np.random.default_rng(2)
    D = np.clip(rng.normal(0.2, 0.5, size=(60, 10)), 0, 1) @ A.T + rng.normal(0, 1e-3, size=(60, A.shape[0]))
    r = solve_bounded(A, D, smoothing=(0.0, 0.5), relative=True, max_iter=1)
    assert not r.converged
    assert any("did not settle" in w for w in r.warnings)
    assert np.all((r.weights >= 0) & (r.weights <= 1))


def test_per_marker_mask_and_residual_stats():
    A = localised_basis()
    M = A.shape[0] // 3
    rng = np.random.default_rng(3)
    D = rng.uniform(0, 1, size=(20, A.shape[1])) @ A.T
    vis = np.ones((20, M))
    vis[5, :] = 0  # a frame with nothing visible
    vis[:, 3] = 0  # a marker never visible
    r = solve_bounded(A, D, mask=vis, dims=3)
    st = residual_stats(r, dims=3, observed=vis > 0)
    assert np.isnan(st.frame_rms[5]) and np.isnan(st.marker_rms[3])
    assert np.nanmax(st.frame_rms) < 1e-6
    assert not r.solved[5] and r.solved.sum() == 19


def test_conditioning_names_a_near_duplicate_pair():
    A = localised_basis(K=8)
    names = ["browUp", "blink", "jawOpen", "mouthLeft", "smile", "cheekPuff", "jawLeft", "funnel"]
    A = A.copy()
    A[:, 6] = 0.8 * A[:, 3] + 1e-5 * np.random.default_rng(4).normal(size=A.shape[0])
    notes = basis_warnings(A, names)
    # one line that says what to do, with the config line to do it
    assert any(n.startswith("mouthLeft and jawLeft move these markers the same way") and
               n.endswith("lock the one you do not need: [solve] locks = { jawLeft = 0 }") for n in notes), notes
    assert not any("browUp and" in n for n in notes)


def test_conditioning_reports_a_dependent_group_and_masked_markers():
    A = localised_basis(K=6)
    names = ["a", "b", "c", "d", "e", "f"]
    A = A.copy()
    A[:, 5] = 0.5 * A[:, 0] + 0.5 * A[:, 1]  # f = mix of a and b: no pair is a duplicate, the triple is
    cond = basis_conditioning(A, names)
    assert any(set(g) == {0, 1, 5} for g, _ in cond.groups)
    line = next(n for n in cond.warnings if n.startswith("a, b, f together move these markers"))
    assert line.endswith(("locks = { a = 0 }", "locks = { b = 0 }", "locks = { f = 0 }")), line
    # shape e seen only by markers that are all occluded
    mask = np.ones(A.shape[0])
    mask[np.abs(A[:, 4]) > 0] = 0
    notes = basis_warnings(A, names, mask=mask)
    assert any(n.startswith("e moves none of these markers") for n in notes)


def test_diagnostics_validate_input():
    from facecap.solvers import FacecapError

    with pytest.raises(FacecapError, match="`shape_names` must have 3"):
        basis_warnings(np.eye(3), ["a"])
    with pytest.raises(FacecapError, match="`mask` must have shape"):
        basis_warnings(np.eye(3), ["a", "b", "c"], mask=np.ones(4))
