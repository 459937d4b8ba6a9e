"""The batched bounded solve agrees with scipy's BVLS, frame by frame."""

import numpy as np
import pytest
from scipy.optimize import lsq_linear

from facecap.solvers import FacecapError, solve_bounded


def reference(A, d, lam, lo, hi):
    ok = np.isfinite(d)
    K = A.shape[1]
    M = np.vstack([A[ok], np.sqrt(lam) * np.eye(K)])
    b = np.concatenate([d[ok], np.zeros(K)])
    return lsq_linear(M, b, bounds=(lo, hi), method="bvls", tol=1e-15).x


@pytest.mark.parametrize("lam", [1e-6, 1e-3])
def test_matches_bvls_with_gaps(lam):
    rng = np.random.default_rng(0)
    P, K, F = 90, 20, 300
    A = rng.normal(size=(P, K)) * 0.01
    truth = np.clip(rng.normal(0.3, 0.5, size=(F, K)), 0, 1)
    D = truth @ A.T + rng.normal(0, 0.002, size=(F, P))
    D[rng.random((F, P)) < 0.05] = np.nan
    res = solve_bounded(A, D, regularisation=lam)
    for f in range(0, F, 7):
        np.testing.assert_allclose(res.weights[f], reference(A, D[f], lam + 1e-12 * np.mean((A**2).sum(0)), 0, 1), atol=1e-6)
    assert np.all((res.weights >= 0) & (res.weights <= 1))
    assert res.at_bound.sum() > 0


def test_noise_free_recovery_is_exact():
    rng = np.random.default_rng(1)
    A = rng.normal(size=(60, 12))
    truth = rng.uniform(0, 1, size=(50, 12))
    res = solve_bounded(A, truth @ A.T)
    np.testing.assert_allclose(res.weights, truth, atol=1e-9)


def test_frames_without_data_are_reported_not_invented():
    A = np.eye(3)
    D = np.array([[0.5, 0.2, 0.1], [np.nan, np.nan, np.nan]])
    res = solve_bounded(A, D)
    assert res.solved.tolist() == [True, False]
    assert np.isnan(res.weights[1]).all()
    assert "no visible markers" in res.warnings[0]


def test_input_validation_names_the_argument():
    with pytest.raises(FacecapError, match="`D` must have shape"):
        solve_bounded(np.eye(3), np.zeros((2, 4)))
    with pytest.raises(FacecapError, match="`lower` must not exceed"):
        solve_bounded(np.eye(3), np.zeros((2, 3)), lower=1, upper=0)
