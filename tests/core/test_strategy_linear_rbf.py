"""linear (cloning matrix) and rbf (Pyun): exact on noiseless examples, warnings, gaps, clamping."""

import numpy as np
import pytest
from numpy.testing import assert_allclose

from facecap.solvers.errors import FacecapError
from facecap.solvers.strategies.linear import LinearStrategy
from facecap.solvers.strategies.rbf import KERNELS, RBFStrategy

from gappy_example_takes import example_takes, weight_errors
from synthetic_face import make_basis


@pytest.fixture(scope="module")
def pairs():
    basis, _ = make_basis(n_markers=30, n_shapes=8, seed=3)
    rng = np.random.default_rng(0)
    W = rng.uniform(0, 1, size=(40, 8)) * (rng.uniform(size=(40, 8)) < 0.5)
    X = np.einsum("fk,kmd->fmd", W, basis.deltas)
    return basis, W, X


def test_linear_is_exact_on_noiseless_examples_and_their_span(pairs):
    basis, W, X = pairs
    s = LinearStrategy(ridge=0.0).fit(basis, examples=X[:30], weights=W[:30])
    assert_allclose(s.solve(X[:30]).weights, W[:30], atol=1e-9)
    assert_allclose(s.solve(X[30:]).weights, W[30:], atol=1e-9)  # held out, same linear relation


def test_linear_warns_when_examples_are_fewer_than_source_dimensions(pairs):
    basis, W, X = pairs
    r = LinearStrategy().fit(basis, examples=X[:30], weights=W[:30]).solve(X[:2])
    assert any("under-determined" in w and "30 example(s) for 90" in w for w in r.warnings)


def test_linear_overdetermined_ridge_path(pairs):
    basis, W, X = pairs
    few = X[:, :4]  # 4 markers = 12 dims < 40 examples: the primal solve
    r = LinearStrategy(ridge=0.0).fit(basis, examples=few, weights=W)
    assert not any("under-determined" in w for w in r.notes)
    assert r.matrix.shape == (8, 12)


def test_linear_fills_gaps_and_clamps(pairs):
    basis, W, X = pairs
    s = LinearStrategy(ridge=0.0).fit(basis, examples=X[:30], weights=W[:30])
    gappy = X[30:].copy()
    gappy[0, 12] = np.nan
    r = s.solve(gappy)
    assert_allclose(r.weights, W[30:], atol=1e-9)
    assert any("gaps" in w for w in r.warnings)
    r = s.solve(3 * X[30:31])
    assert r.weights.max() <= 1.0 and r.clamped[0] > 0


def test_linear_rejects_bad_pairs(pairs):
    basis, W, X = pairs
    with pytest.raises(FacecapError, match=r"`weights` must have shape \(30, 8\)"):
        LinearStrategy().fit(basis, examples=X[:30], weights=W[:29])
    bad = X[:30].copy()
    bad[0, 0] = np.nan
    with pytest.raises(FacecapError, match="no gaps"):
        LinearStrategy().fit(basis, examples=bad, weights=W[:30])


@pytest.mark.parametrize("kernel", ["thin_plate_spline", "gaussian", "multiquadric", "cubic"])
def test_rbf_reproduces_its_examples(pairs, kernel):
    basis, W, X = pairs
    s = RBFStrategy(kernel=kernel, n_components=8).fit(basis, examples=X[:30], weights=W[:30], training=X)
    assert_allclose(s.solve(X[:30]).weights, W[:30], atol=1e-9)


def test_rbf_warns_far_from_examples_and_clamps(pairs):
    basis, W, X = pairs
    s = RBFStrategy().fit(basis, examples=X[:30], weights=W[:30])
    r = s.solve(np.concatenate([X[:1], 4 * X[5:6]]))
    assert r.info["extrapolated_frames"] == 1
    assert any("from every example" in w for w in r.warnings)
    assert np.all((r.weights >= 0) & (r.weights <= 1))


def test_rbf_keeps_its_linear_tail_with_few_examples(pairs):
    basis, W, X = pairs
    s = RBFStrategy(n_components=8).fit(basis, examples=X[:5], weights=W[:5], training=X)
    assert s.used_degree == 1 and s._components.shape[0] == 4 and any("at most 4 dimensions" in n for n in s.notes)
    assert_allclose(s.solve(X[:5]).weights, W[:5], atol=1e-9)


def test_rbf_options_are_validated():
    assert "thin_plate_spline" in KERNELS
    with pytest.raises(FacecapError, match="unknown kernel"):
        RBFStrategy(kernel="bessel")
    with pytest.raises(FacecapError, match="smoothing"):
        RBFStrategy(smoothing=-1)


@pytest.fixture(scope="module")
def gappy_takes():
    """linear and rbf solved on the take with and without 5 % gaps (``gappy_example_takes``)."""
    takes = example_takes()
    errors = {}
    for strategy in ("linear", "rbf"):
        for label, e in weight_errors(takes, strategy=strategy).items():
            errors[strategy, label] = e
    return errors, takes.gap


def _rmse(e):
    return float(np.sqrt(np.mean(e**2)))


def test_rbf_gaps_do_not_damage_the_feature_space(gappy_takes):
    # the PCA features used to come from the gap-free frames only (the neutral holds): all frames
    # degraded, 0.040 -> 0.115, gap-free ones 0.036 -> 0.164
    errors, gap = gappy_takes
    clean, gappy = errors["rbf", "clean"], errors["rbf", "gappy"]
    assert gap.mean() > 0.5 and (~gap).sum() > 60
    assert _rmse(gappy[~gap]) <= _rmse(clean[~gap]) + 0.01  # 0.034 vs 0.036
    assert _rmse(gappy[gap]) <= _rmse(clean[gap]) + 0.01  # 0.042 vs 0.041
    assert _rmse(gappy) <= 1.15 * _rmse(clean)


def test_linear_gaps_cost_little(gappy_takes):
    # the examples with gaps used to be filled through the gap-free frames' span: 0.038 -> 0.0425 on gap frames
    errors, gap = gappy_takes
    clean, gappy = errors["linear", "clean"], errors["linear", "gappy"]
    assert _rmse(gappy[gap]) <= _rmse(clean[gap]) + 0.003  # 0.039 vs 0.038
    assert _rmse(gappy[~gap]) <= _rmse(clean[~gap]) + 0.003


def test_pca_gappy_recovers_the_span_the_gap_free_rows_miss():
    from facecap.solvers.strategies.lowrank import pca, pca_gappy

    rng = np.random.default_rng(1)
    basis = np.linalg.qr(rng.normal(size=(40, 4)))[0].T  # (4, 40) orthonormal
    X = rng.normal(size=(300, 4)) @ basis + 0.01 * rng.normal(size=(300, 40))
    X[:50] = 0.01 * rng.normal(size=(50, 40))  # the only gap-free rows: neutral, noise
    gappy = X.copy()
    gappy[50:][rng.uniform(size=(250, 40)) < 0.05] = np.nan
    gappy[np.arange(50, 300), rng.integers(40, size=250)] = np.nan  # every expressive row has a gap
    cos = np.linalg.svd(pca_gappy(gappy, center=False, n_components=4)[1] @ basis.T, compute_uv=False)
    assert cos.min() > 0.99
    assert np.linalg.svd(pca(X[:50], center=False, n_components=4)[1] @ basis.T, compute_uv=False).min() < 0.5
    for a, b in zip(pca_gappy(X, n_components=3), pca(X, n_components=3)):  # no gaps: plain pca
        assert_allclose(a, b)
    # a long take learns from evenly spaced rows (speed): the same span
    long = np.concatenate([gappy] * 10)
    cos = np.linalg.svd(pca_gappy(long, center=False, n_components=4, max_rows=400)[1] @ basis.T, compute_uv=False)
    assert cos.min() > 0.99
