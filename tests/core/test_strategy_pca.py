"""pca: full-rank reconstruction, Chuang & Bregler basis frames, related basis = PCR, FastICA, posed solve."""

import numpy as np
import pytest
from numpy.testing import assert_allclose

from facecap.solvers.errors import FacecapError
from facecap.solvers.strategies.pca import PCAStrategy, farthest_frames, fast_ica

from synthetic_face import make_basis


@pytest.fixture(scope="module")
def take():
    basis, _ = make_basis(n_markers=30, n_shapes=6, seed=4)
    rng = np.random.default_rng(0)
    W = rng.uniform(0, 1, size=(120, 6)) * (rng.uniform(size=(120, 6)) < 0.6)
    X = np.einsum("fk,kmd->fmd", W, basis.deltas)
    return basis, W, X


def test_full_rank_reproduces_the_training_frames(take):
    basis, W, X = take
    for ica in (False, True):
        s = PCAStrategy(variance=1.0, ica=ica).learn_basis(X)
        assert s.components.shape[0] == 6  # the take's rank
        assert_allclose(s.reconstruct(X), X, atol=1e-12)


def test_basis_frames_are_the_extreme_projections(take):
    basis, W, X = take
    s = PCAStrategy(variance=1.0, n_basis=3).learn_basis(X)
    coef = (X.reshape(len(X), -1) - s.mean) @ s.components.T
    for frame, c, which in s.basis_frames:
        assert frame == (np.argmin if which == "min" else np.argmax)(coef[:, c])
    assert len(s.frames_to_pose()) <= 6


def test_related_basis_is_principal_component_regression(take):
    basis, W, X = take
    s = PCAStrategy(mode="related", n_components=4).fit(basis, training=X, example_weights=W)
    # The thesis' related basis over all training frames: W_rel = Phi'^T B Lambda^-1 (centred).
    Xc = X.reshape(len(X), -1) - s.mean
    C = Xc @ s.components.T
    related = (W - W.mean(axis=0)).T @ C @ np.linalg.inv(C.T @ C)
    assert_allclose(s.related, related, atol=1e-9)
    full = PCAStrategy(mode="related", variance=1.0).fit(basis, training=X, example_weights=W)
    assert_allclose(full.solve(X).weights, W, atol=1e-9)  # full rank, linear data: exact


def test_fast_ica_recovers_mixed_laplacian_sources():
    rng = np.random.default_rng(3)
    S = rng.laplace(size=(3000, 3))
    mixed = S @ rng.normal(size=(3, 9))
    s = PCAStrategy(n_components=3, ica=True).learn_basis(mixed.reshape(3000, 3, 3))
    recovered = s.coefficients(mixed)
    corr = np.abs(np.corrcoef(S.T, recovered.T)[:3, 3:])
    assert np.all(corr.max(axis=1) >= 0.95)
    again = PCAStrategy(n_components=3, ica=True).learn_basis(mixed.reshape(3000, 3, 3))
    assert_allclose(again.components, s.components)  # deterministic
    Z = rng.normal(size=(500, 2))
    U, ok = fast_ica(Z / Z.std(axis=0))
    assert_allclose(U @ U.T, np.eye(2), atol=1e-9)


def test_posed_basis_frames_give_back_their_posed_weights(take):
    basis, W, X = take
    s = PCAStrategy(mode="posed", variance=1.0, smoothing=(0.0, 0.0), regularisation=1e-9).learn_basis(X)
    frames = s.frames_to_pose()
    s.fit(basis, training=X, example_frames=frames, example_weights=W[frames])
    r = s.solve(X[frames])
    assert_allclose(r.weights, W[frames], atol=2e-3)
    assert np.all(r.source_weights >= 0)


def test_weights_are_required_and_name_the_frames_to_pose(take):
    basis, W, X = take
    with pytest.raises(FacecapError, match="pose the character at training frames"):
        PCAStrategy(mode="posed").fit(basis, training=X)


def test_farthest_frames_cover_the_take(take):
    basis, W, X = take
    picks = farthest_frames(X, 10)
    assert len(picks) == 10 and len(set(picks)) == 10
    assert np.argmin(np.linalg.norm(X, axis=(1, 2))) in picks  # the frame nearest the neutral
    spread = lambda idx: np.min(np.linalg.norm(X[:, None] - X[None, idx], axis=(2, 3)), axis=1).max()
    assert spread(picks) < spread(np.arange(10))  # covers the take better than the first 10 frames
